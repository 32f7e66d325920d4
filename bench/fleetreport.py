"""`lpam fleet report` for a big fleet, from a real git repository: gathering and drawing.

    python -m bench.fleetreport --cars 100 --days 30

Builds a repository like a fleet's after a month: `main` with a desired state that
declares a rollout, and one `status/<vehicle>` branch per car holding what the car
publishes (status.json through core/publication.py, timeline.json in the published
timeline's format) — a month of a car that switches its controller one to three times a
day, a few deferrals and, now and then, a rollback among its last passes. Then times
`write_report` (workflow/fleetreport.py): reading every branch, judging every car,
drawing the page. bench/fleetpage.py times the drawing alone.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import sys
import tempfile
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

from dulwich.objects import Blob, Commit, ObjectID, Tree
from dulwich.refs import Ref
from dulwich.repo import Repo

from reconciler.core.publication import status_file
from reconciler.workflow.fleetreport import write_report
from schemas.agent import AgentStatus, Attempt
from schemas.fleet import PublishedApp
from schemas.rollout import RolloutState
from schemas.timeline import Edge, Stamp

NOW = datetime(2026, 11, 28, 6, 0, tzinfo=timezone.utc)
DESIRED = """\
version: 2
apps: [ctl-b]
rollout:
  waves: [[car-001], [car-002, car-003], ["*"]]
  prove_seconds: 600
  silent_seconds: 7200
"""


def build(path: Path, cars: int, days: int, seed: int = 34) -> None:
    """The fleet repository at `path` (a non-bare repository's .git, as a clone has)."""
    pick = random.Random(seed)
    repo = Repo.init(str(path), mkdir=True)
    tip = _commit(repo, {"desired-state.yaml": DESIRED.encode()}, "R2", NOW)
    repo.refs[Ref(b"refs/heads/main")] = tip
    for number in range(1, cars + 1):
        vehicle = f"car-{number:03d}"
        edges, passes = _month(pick, days)
        stage = "proven" if number > 3 or pick.random() < 0.9 else "rolled back"
        status = AgentStatus(
            vehicle=vehicle, follows="desired-state.yaml", desired_revision=tip.decode(),
            applied_revision=tip.decode(), last_attempt=passes[-1], passes=passes,
            rollout=RolloutState(revision=tip.decode(), wave=min(number, 3), stage=stage,
                                 since=(NOW - timedelta(hours=2)).isoformat()))
        app = PublishedApp(name="ctl-b", generation="4c1e2a3b9f00-0a1b2c3d", status="running",
                           running=True)
        timeline = {"version": 1, "vehicle": vehicle, "software": {},
                    "edges": [e.model_dump(mode="json", exclude_none=True) for e in edges]}
        files = {"status.json": status_file(status, [app]),
                 "timeline.json": json.dumps(timeline, separators=(",", ":")).encode()}
        repo.refs[Ref(f"refs/heads/status/{vehicle}".encode())] = _commit(
            repo, files, f"status of {vehicle}", NOW - timedelta(minutes=pick.randint(1, 300)))


def _month(pick: random.Random, days: int) -> tuple[list[Edge], list[Attempt]]:
    edges: list[Edge] = []
    moment, boot = NOW - timedelta(days=days), 0
    app = "ctl-a"
    while moment < NOW - timedelta(hours=8):
        boot += 1
        stamp = Stamp(boot=f"boot-{boot}", mono=60.0, wall=moment)
        edges.append(Edge(kind="began", how="apply", at=stamp, app=app,
                          generation=f"{pick.getrandbits(48):012x}-0a1b2c3d"))
        moment += timedelta(hours=pick.uniform(8, 24))
        end = Stamp(boot=f"boot-{boot}", mono=3600.0, wall=min(moment, NOW))
        how = "rollback" if pick.random() < 0.03 else "apply"
        edges.append(Edge(kind="ended", how=how, at=end, app=app,
                          generation=edges[-1].generation))
        app = pick.choice(("ctl-a", "ctl-b", "pandarecord"))
    passes = [Attempt(time=(NOW - timedelta(minutes=5 * n)).isoformat(), revision="r",
                      result=pick.choice(("nothing to do", "nothing to do", "deferred")),
                      reason="the car moves (14 km/h)") for n in range(10, 0, -1)]
    return edges, passes


def _commit(repo: Repo, files: dict[str, bytes], message: str, when: datetime) -> ObjectID:
    tree = Tree()
    for name, data in files.items():
        blob = Blob.from_string(data)
        repo.object_store.add_object(blob)
        tree.add(name.encode(), 0o100644, blob.id)
    repo.object_store.add_object(tree)
    commit = Commit()
    commit.tree, commit.message = tree.id, message.encode()
    commit.author = commit.committer = b"car <car@fleet>"
    commit.author_time = commit.commit_time = int(when.timestamp())
    commit.author_timezone = commit.commit_timezone = 0
    repo.object_store.add_object(commit)
    return commit.id


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cars", type=int, default=100)
    parser.add_argument("--days", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        build(Path(tmp) / "fleet", args.cars, args.days)
        times = []
        for _ in range(args.rounds):
            began = time.perf_counter()
            page = write_report(Path(tmp) / "fleet", Path(tmp) / "out", now=NOW)
            times.append(time.perf_counter() - began)
        size = page.stat().st_size
    print(f"| lpam fleet report: {args.cars} cars x {args.days} days, from a repository | "
          f"median of {args.rounds} | page |\n|---|---:|---:|")
    print(f"| gather (every status branch, every timeline) and draw | "
          f"{statistics.median(times) * 1000:.0f} ms | {size / 1024:.0f} KiB |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
