"""`lpam fleet report`'s gathering (workflow/fleetreport.py) from a real repository: a
car's timeline from its published provenance timeline, else from its status alone."""

from __future__ import annotations

import json
from datetime import timedelta
from pathlib import Path

from dulwich.refs import Ref
from dulwich.repo import Repo

from bench.fleetreport import DESIRED, NOW, _commit, _month
from reconciler.core.publication import status_file
from reconciler.workflow.fleetreport import gather
from schemas.agent import AgentStatus
from schemas.fleet import LastChange, PublishedApp

APP = PublishedApp(name="ctl-a", generation="4c1e2a3b9f00-0a1b2c3d", status="running",
                   running=True)


def fleet(path: Path, *, timeline: bool) -> None:
    repo = Repo.init(str(path), mkdir=True)
    repo.refs[Ref(b"refs/heads/main")] = _commit(repo, {"desired-state.yaml":
                                                        DESIRED.encode()}, "R", NOW)
    status = AgentStatus(vehicle="car-09", applied_revision="r", desired_revision="r")
    change = LastChange(time=(NOW - timedelta(days=2)).isoformat(), result="applied",
                        apps=["ctl-a@4c1e2a3b9f00-0a1b2c3d"])
    files = {"status.json": status_file(status, [APP], change=change)}
    if timeline:
        import random

        edges, _ = _month(random.Random(1), 30)
        files["timeline.json"] = json.dumps({"version": 1, "vehicle": "car-09", "software": {},
                                             "edges": [e.model_dump(mode="json",
                                                                    exclude_none=True)
                                                       for e in edges]}).encode()
    repo.refs[Ref(b"refs/heads/status/car-09")] = _commit(repo, files, "status", NOW)


def test_a_car_that_publishes_no_timeline_shows_what_its_status_says_runs(
        tmp_path: Path) -> None:
    fleet(tmp_path / "fleet", timeline=False)
    (car,) = gather(tmp_path / "fleet", now=NOW).cars
    (ran,) = car.marks
    assert (ran.kind, ran.start, ran.end) == ("ran", NOW - timedelta(days=2), None)
    assert ran.label.startswith("ctl-a@4c1e2a3b9f00") and "publishes no timeline" in ran.label


def test_a_published_timeline_gives_what_ran_over_the_month(tmp_path: Path) -> None:
    fleet(tmp_path / "fleet", timeline=True)
    (car,) = gather(tmp_path / "fleet", now=NOW).cars
    ran = [m for m in car.marks if m.kind == "ran"]
    assert len(ran) > 20  # a month of one to three switches a day
    assert not any("publishes no timeline" in m.label for m in ran)
    assert min(m.start for m in ran) >= NOW - timedelta(days=30)
