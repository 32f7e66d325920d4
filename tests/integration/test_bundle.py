"""Offline bundles: made on a laptop from the fleet's repository (real git daemon), then
applied on a car with the server gone — the same result as a sync over the network."""

from __future__ import annotations

from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.conftest import fleet_state


def test_a_bundle_converges_a_car_with_no_network_at_all(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    fleet.commit("car 07 runs beta", {"vehicles/rav4-07.yaml": fleet_state("beta", MODE="b")})
    fleet.push()
    laptop = Lpam(tmp_path / "laptop")
    out = tmp_path / "usb" / "fleet.bundle"
    out.parent.mkdir()
    made = laptop("bundle", "create", str(out), "--source", git_daemon.url("fleet.git"))
    assert made.returncode == 0, made.stdout + made.stderr
    assert "desired-state.yaml: 1 repository\n" in made.stdout  # both files were read
    assert "vehicles/rav4-07.yaml: 1 repository\n" in made.stdout
    git_daemon.stop()  # in the field: no server, no WiFi
    done = car("sync", "--bundle", str(out), "--network-timeout", "5")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Sync: applied" in done.stdout
    assert car.events() == ["beta:install:b", "beta:start:b"]
    assert car.status()["agent"]["applied_revision"] == fleet.rev("HEAD")
    again = car("sync", "--bundle", str(out), "--network-timeout", "5")
    assert again.returncode == 0 and "Sync: nothing to do" in again.stdout


def test_a_bundle_of_another_source_is_refused_and_changes_nothing(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    other = RepoBuilder(git_daemon.base, "other-fleet.git", work_root=tmp_path / "w",
                        home=Path(fleet.env["HOME"]))
    other.commit("other", {"desired-state.yaml": fleet_state("beta")})
    other.push()
    out = tmp_path / "other.bundle"
    made = Lpam(tmp_path / "laptop")("bundle", "create", str(out), "--source",
                                     git_daemon.url("other-fleet.git"))
    assert made.returncode == 0, made.stderr
    done = car("sync", "--bundle", str(out))
    assert done.returncode == 1
    assert "this bundle is of" in done.stderr and "this car follows" in done.stderr
    assert car.events() == []


def test_a_file_that_is_not_a_bundle_is_refused(car: Lpam, fleet: RepoBuilder,
                                                  tmp_path: Path) -> None:
    junk = tmp_path / "junk.bundle"
    junk.write_bytes(b"# v2 git bundle\nnot really\n")
    done = car("sync", "--bundle", str(junk))
    assert done.returncode == 1 and "junk.bundle" in done.stderr
    assert "Traceback" not in done.stderr
    assert car.events() == []
