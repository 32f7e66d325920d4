"""`lpam provenance` without the car (issue 33): the car's agent publishes its timeline
beside its status on `status/<vehicle>` of the fleet repository (a real git daemon that
accepts pushes, one push for both), and the CLI, in a plain `git clone` on a laptop,
answers for a moment of that car — with what ran, the same as on the car — and refuses
clearly what it cannot answer."""

from __future__ import annotations

import json
import subprocess
from datetime import datetime, timezone
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam


def test_a_fleet_clone_answers_for_the_cars_published_timeline(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    assert car("sync").returncode == 0  # applies alpha, publishes status and timeline
    now = datetime.now(timezone.utc).isoformat()
    on_car = car("provenance", "--at", now, "--json")
    assert on_car.returncode == 0, on_car.stderr
    [answer] = json.loads(on_car.stdout)
    assert answer["verdict"] == "ran"
    assert [r["app"] for r in answer["ran"]] == ["alpha"]

    clone = tmp_path / "laptop-clone"
    subprocess.run(["git", "clone", "--quiet", git_daemon.url("fleet.git"), str(clone)],
                   env=fleet.env, check=True, capture_output=True)
    laptop = Lpam(tmp_path / "laptop")
    remote = laptop("provenance", "--repo", str(clone), "--vehicle", "rav4-07", "--at", now,
                    "--json")
    assert remote.returncode == 0, remote.stderr
    assert json.loads(remote.stdout) == [answer]  # the same answer, without the car
    text = laptop("provenance", "--repo", str(clone), "--at", now).stdout
    assert "alpha" in text and answer["ran"][0]["software"]["commit"][:12] in text

    unknown = laptop("provenance", "--repo", str(clone), "--vehicle", "rav4-99", "--at", now)
    assert unknown.returncode == 1
    assert "no published timeline of rav4-99" in unknown.stderr and "rav4-07" in unknown.stderr
    assert "Traceback" not in unknown.stderr
    early = laptop("provenance", "--repo", str(clone), "--at", "2001-01-01T00:00:00Z")
    assert early.returncode == 0 and "before lpam" in early.stdout
    bad = laptop("provenance", "--at", "yesterday-ish")
    assert bad.returncode == 2 and "is not a time" in bad.stderr
