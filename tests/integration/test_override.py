"""A local override: a car that follows a fleet repository is steered on the spot (the
phone over Bluetooth, `libpanda-app-manager`), and the edit holds until it is released.

What a user checks, end to end with the real CLI, the real shim, a real git daemon serving
the fleet's repository and the app repository, and app scripts that leave a trace: the
switch is applied at once; `lpam status` says the car runs a local override; the agent's
next pass does not undo it, even when the fleet moves on; `lpam apply --release` ends it
and the car runs the fleet's file again; the car's published status shows the override.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import Any

from tests.gitserver import RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.conftest import fleet_state


def shim(car: Lpam, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "reconciler.frontends.shim", *args],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "LPAM_ROOT": str(car.root)})


def agent_status(car: Lpam) -> dict[str, Any]:
    found: dict[str, Any] = json.loads((car.root / "var/lib/lpam/status.json").read_text())
    return found


def test_a_local_switch_holds_against_the_agent_until_released(
    car: Lpam, fleet: RepoBuilder,
) -> None:
    assert car("sync").returncode == 0
    assert car.events() == ["alpha:install:one", "alpha:start:one"]
    local = car.root / "etc/lpam/desired-state.yaml"
    assert not local.exists()  # a fleet car has no local file

    switched = shim(car, "-i", "beta")
    assert switched.returncode == 0, switched.stderr
    assert car.events()[-2:] == ["beta:install:", "beta:start:"]
    assert car.status()["app"]["name"] == "beta"
    assert car.status()["override"]["by"] == "libpanda-app-manager"
    assert "Local override" in car("status").stdout
    assert "made on this car from the fleet's" in local.read_text().lower()

    fleet.commit("two", {"desired-state.yaml": fleet_state("alpha", MODE="two")})
    fleet.push()
    passed = car("sync")
    assert passed.returncode == 0, passed.stderr
    assert car.status()["app"]["name"] == "beta"  # not undone
    assert "local override" in agent_status(car)["passes"][-1]["reason"]
    assert agent_status(car)["applied_revision"] != fleet.rev("HEAD")  # the fleet waits

    released = car("apply", "--release", "--yes")
    assert released.returncode == 0, released.stderr
    assert "Ended the local override" in released.stdout
    assert car.status()["override"] is None and not local.exists()
    assert car.status()["app"]["name"] == "alpha"
    assert car("sync").returncode == 0  # and the next pass follows the fleet's new commit
    assert agent_status(car)["applied_revision"] == fleet.rev("HEAD")
    assert car.status()["app"]["params"] == {"MODE": "two"}


def test_the_published_status_shows_the_override(car: Lpam, fleet: RepoBuilder) -> None:
    assert car("sync").returncode == 0
    assert shim(car, "-i", "beta").returncode == 0
    assert car("sync").returncode == 0
    published = subprocess.run(["git", "show", "status/rav4-07:status.json"], cwd=fleet.bare,
                               capture_output=True, text=True, timeout=30, check=True)
    body = json.loads(published.stdout)
    assert body["version"] == 3 and body["app"]["name"] == "beta"
    assert body["override"]["by"] == "libpanda-app-manager"
    clone = car.root.parent / "clone"
    subprocess.run(["git", "clone", "-q", "--mirror", str(fleet.bare), str(clone)],
                   check=True, timeout=60)
    shown = car("fleet", "status", "--repo", str(clone))
    assert shown.returncode == 0, shown.stderr
    assert "beta (local override: libpanda-app-manager since" in shown.stdout
