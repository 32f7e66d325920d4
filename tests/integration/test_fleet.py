"""Fleet-wide status from git alone: two cars sync from the same repository (a real git
daemon that accepts pushes), each pass pushes `status/<vehicle>`, and `lpam fleet status`
in a plain `git clone` of the repository shows both — which revision each applied, its
app, and a car stuck on a broken commit."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.conftest import fleet_state, following


def second_car(tmp_path: Path, git_daemon: GitDaemon) -> Lpam:
    return following(tmp_path / "car-01", git_daemon.url("fleet.git"), "rav4-01")


def test_fleet_status_shows_every_car_from_a_clone(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    other = second_car(tmp_path, git_daemon)
    fleet.commit("car 01 runs beta", {"vehicles/rav4-01.yaml": fleet_state("beta")})
    fleet.push()
    assert car("sync").returncode == 0 and other("sync").returncode == 0
    good = fleet.rev("HEAD")
    fleet.commit("typo for car 07", {"vehicles/rav4-07.yaml": "version: 1\naap: x\n"})
    fleet.push()
    assert car("sync").returncode == 1  # rav4-07 stays on the good revision
    clone = tmp_path / "laptop-clone"
    subprocess.run(["git", "clone", "--quiet", git_daemon.url("fleet.git"), str(clone)],
                   env=fleet.env, check=True, capture_output=True)
    done = Lpam(tmp_path / "laptop")("fleet", "status", "--repo", str(clone), "--json")
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["tip"] == fleet.rev("HEAD")
    rows = {r["vehicle"]: r for r in report["vehicles"]}
    assert set(rows) == {"rav4-01", "rav4-07"}
    assert rows["rav4-01"]["app"] == "beta" and rows["rav4-01"]["applied"] == good
    assert rows["rav4-07"]["app"] == "alpha" and rows["rav4-07"]["applied"] == good
    assert rows["rav4-07"]["last_pass"] == "failed" and "aap" in rows["rav4-07"]["reason"]
    assert rows["rav4-07"]["up_to_date"] is False
    # which file each car follows, even one whose file has a fault, and how old its report is
    assert rows["rav4-01"]["follows"] == "vehicles/rav4-01.yaml"
    assert rows["rav4-07"]["follows"] == "vehicles/rav4-07.yaml"
    assert all(isinstance(r["age_seconds"], int) and r["age"].endswith(" ago")
               for r in rows.values())
    table = Lpam(tmp_path / "laptop")("fleet", "status", "--repo", str(clone)).stdout
    assert "rav4-07" in table and "failed" in table and "rav4-01" in table
    assert "vehicles/rav4-07.yaml" in table and "Last report" in table


def test_a_car_does_not_fetch_the_other_cars_status(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    other = second_car(tmp_path, git_daemon)
    assert other("sync").returncode == 0 and car("sync").returncode == 0
    refs = subprocess.run(
        ["git", "--git-dir", str(car.root / "var/lib/lpam/repositories/+source/.git"),
         "for-each-ref", "--format=%(refname)"], capture_output=True, text=True,
        check=True).stdout.split()
    assert "refs/remotes/origin/status/rav4-07" in refs  # its own, as it pushed it
    assert "refs/remotes/origin/status/rav4-01" not in refs
