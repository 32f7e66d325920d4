"""`lpam fleet status`: the whole fleet from git alone.

Each car publishes its status to the branch `status/<vehicle>` of the desired-state
repository when it changed and at least every heartbeat (workflow/sync.py `publish`,
reconciler/publication.py). In any clone of that repository, after a fetch, this reads
those branches and says per vehicle which file of the repository it follows, which
revision it applied against the branch the cars follow, its app, whether it runs, how its
last pass ended, and how old its last report is — no server, no database, nothing but refs
and one small file per car. The age is measured against the clock the caller passes in.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from reconciler.errors import ConfigError
from reconciler.text import printable

PREFIXES = (b"refs/remotes/origin/status/", b"refs/heads/status/")


@dataclass(frozen=True)
class Vehicle:
    vehicle: str
    follows: str | None  # vehicles/<id>.yaml or desired-state.yaml (None: not reported)
    applied: str | None
    up_to_date: bool | None  # applied == the followed branch's tip (None: unknown)
    app: str | None
    running: bool | None
    last_pass: str | None
    reason: str | None
    last_seen: str  # when the car last reported (its status commit's time)


def read(repo_path: Path, branch: str = "main") -> tuple[str | None, list[Vehicle]]:
    """(the followed branch's tip, one row per vehicle with a status branch)."""
    from dulwich.errors import NotGitRepository
    from dulwich.objects import Commit, Tree
    from dulwich.refs import Ref
    from dulwich.repo import Repo

    try:
        repo = Repo(str(repo_path))
    except NotGitRepository:
        raise ConfigError("not a clone of the desired-state repository", path=repo_path,
                          hint="run it in a clone (git clone …; git fetch) or pass --repo") \
            from None
    with repo:
        refs = repo.get_refs()
        tip_id = refs.get(Ref(f"refs/remotes/origin/{branch}".encode())) or \
            refs.get(Ref(f"refs/heads/{branch}".encode()))
        tip = tip_id.decode("ascii") if tip_id else None
        seen: dict[str, Vehicle] = {}
        for name, sha in sorted(refs.items()):
            prefix = next((p for p in PREFIXES if name.startswith(p)), None)
            if prefix is None or sha is None:
                continue
            vehicle = name[len(prefix):].decode("utf-8", "replace")
            commit = repo[sha]
            if not isinstance(commit, Commit) or vehicle in seen:
                continue
            tree = repo[commit.tree]
            assert isinstance(tree, Tree)
            try:
                _, blob_id = tree[b"status.json"]
                body: dict[str, Any] = json.loads(repo[blob_id].as_raw_string())
            except (KeyError, ValueError):
                continue
            seen[vehicle] = _row(vehicle, body, tip, commit.commit_time)
    return tip, list(seen.values())


def _row(vehicle: str, body: dict[str, Any], tip: str | None, when: int) -> Vehicle:
    agent = body.get("agent") or {}
    app = body.get("app") or {}
    last = agent.get("last_attempt") or {}
    applied = agent.get("applied_revision")
    return Vehicle(
        vehicle=vehicle, follows=agent.get("follows"), applied=applied,
        up_to_date=None if tip is None or applied is None else applied == tip,
        app=app.get("name"), running=app.get("running"), last_pass=last.get("result"),
        reason=last.get("reason"),
        last_seen=datetime.fromtimestamp(when, timezone.utc).isoformat(timespec="seconds"))


def age(row: Vehicle, now: datetime) -> float:
    """Seconds since the car's last report, by `now` (negative: the car's clock is ahead)."""
    return (now - datetime.fromisoformat(row.last_seen)).total_seconds()


def ago(seconds: float) -> str:
    """An age as people say it: "45 s ago", "12 min ago", "3 h ago", "4 d ago"."""
    if seconds < -60:
        return f"{ago(-seconds).removesuffix(' ago')} ahead (the car's clock)"
    seconds = max(seconds, 0)
    for unit, size, below in (("s", 1, 60), ("min", 60, 3600), ("h", 3600, 48 * 3600)):
        if seconds < below:
            return f"{int(seconds // size)} {unit} ago"
    return f"{int(seconds // 86400)} d ago"


def as_json(tip: str | None, rows: list[Vehicle], *, now: datetime) -> dict[str, Any]:
    return {"tip": tip, "vehicles": [{**asdict(row), "age_seconds": int(age(row, now)),
                                      "age": ago(age(row, now))} for row in rows]}


def as_table(tip: str | None, rows: list[Vehicle], *, now: datetime) -> str:
    if not rows:
        return ("No vehicle has published its status yet (no status/* branches: fetch, or "
                "check that the cars may push to this repository).")
    header = ("Vehicle", "Follows", "Applied", "Current", "App", "Running", "Last pass",
              "Last report")
    cells: list[tuple[str, ...]] = [(r.vehicle, r.follows or "?", (r.applied or "none")[:12],
              {True: "yes", False: "no", None: "?"}[r.up_to_date], r.app or "-",
              {True: "yes", False: "no", None: "?"}[r.running],
              (r.last_pass or "-") + (f": {r.reason}" if r.reason else ""),
              ago(age(r, now)))
             for r in rows]
    cells = [tuple(printable(v)[:60] for v in row)
             for row in cells]
    widths = [max(len(h), *(len(row[i]) for row in cells)) for i, h in enumerate(header)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths)).rstrip()]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip()
              for row in cells]
    lines.append(f"\nThe cars follow {(tip or 'an unknown revision')[:12]}. A car reports "
                 "when its status changes and at least every\nheartbeat (agent.yaml "
                 "heartbeat_seconds, 6 h unless set): a much older report means it is off "
                 "or offline.")
    return "\n".join(lines)
