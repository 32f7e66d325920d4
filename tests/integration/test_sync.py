"""`lpam sync`: one pass of a vehicle following its desired-state repository, end to end
with the real CLI, a real git daemon serving the fleet's repository and the app
repository beside it, and real app scripts that leave a trace.

What a user checks: a new commit is applied; a broken one leaves the app running, is
recorded with its reason and not retried, and the next good one is applied; a vehicle's
own file wins over the fleet's; what a fetch-only pass brought is applied with no network.
"""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Callable
from typing import Any

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.conftest import fleet_state


def status(car: Lpam) -> dict[str, Any]:
    found: dict[str, Any] = json.loads((car.root / "var/lib/lpam/status.json").read_text())
    return found


def test_a_new_commit_is_applied_and_a_second_pass_has_nothing_to_do(
    car: Lpam, fleet: RepoBuilder,
) -> None:
    done = car("sync")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Sync: applied" in done.stdout
    assert car.events() == ["alpha:install:one", "alpha:start:one"]
    head = fleet.rev("HEAD")
    assert status(car)["applied_revision"] == head == status(car)["desired_revision"]
    again = car("sync")
    assert again.returncode == 0 and "Sync: nothing to do" in again.stdout
    assert car.events() == ["alpha:install:one", "alpha:start:one"]
    fleet.commit("faster", {"desired-state.yaml": fleet_state("alpha", MODE="two")})
    fleet.push()
    assert car("sync").returncode == 0
    assert car.events()[-2:] == ["alpha:stop:one", "alpha:start:two"]


def test_a_broken_commit_is_recorded_not_retried_and_the_next_good_one_applies(
    car: Lpam, fleet: RepoBuilder,
) -> None:
    assert car("sync").returncode == 0
    fleet.commit("typo", {"desired-state.yaml": fleet_state("alpha") + "aap: beta\n"})
    fleet.push()
    broken = fleet.rev("HEAD")
    failed = car("sync")
    assert failed.returncode == 1
    assert "unknown key 'aap'" in failed.stderr and "fleet.git@" in failed.stderr
    assert "/desired-state.yaml:6:1: unknown key 'aap'" in failed.stderr
    assert car.events() == ["alpha:install:one", "alpha:start:one"]  # still running
    last = status(car)["last_attempt"]
    assert (last["revision"], last["result"]) == (broken, "failed")
    assert "unknown key 'aap'" in last["reason"]
    retry = car("sync")  # the same broken revision: not tried again
    assert retry.returncode == 0 and "failed before" in retry.stdout + retry.stderr
    assert status(car)["last_attempt"]["revision"] == broken
    fleet.commit("beta now", {"desired-state.yaml": fleet_state("beta")})
    fleet.push()
    fixed = car("sync")
    assert fixed.returncode == 0, fixed.stderr
    assert car.events()[-4:] == ["alpha:stop:one", "alpha:uninstall:one", "beta:install:",
                                 "beta:start:"]
    assert status(car)["applied_revision"] == fleet.rev("HEAD")


def test_a_vehicles_own_file_wins_over_the_fleets(car: Lpam, fleet: RepoBuilder) -> None:
    fleet.commit("rav4-07 runs beta", {"vehicles/rav4-07.yaml": fleet_state("beta"),
                                       "vehicles/rav4-01.yaml": fleet_state("alpha")})
    fleet.push()
    assert car("sync").returncode == 0
    assert car.events() == ["beta:install:", "beta:start:"]


def test_what_a_fetch_only_pass_brought_is_applied_with_no_network(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon, apps: str,
) -> None:
    assert car("sync").returncode == 0
    fleet.commit("pinned, beta", {"desired-state.yaml": fleet_state("beta", pin=apps)})
    fleet.push()
    fetched = car("sync", "--fetch-only")
    assert fetched.returncode == 0 and "Sync: fetched" in fetched.stdout, fetched.stderr
    assert car.events() == ["alpha:install:one", "alpha:start:one"]  # nothing changed yet
    git_daemon.stop()  # the end of the trip: no WiFi any more
    offline = car("sync", "--network-timeout", "5")
    assert offline.returncode == 0, offline.stdout + offline.stderr
    assert "Sync: applied" in offline.stdout
    assert car.events()[-2:] == ["beta:install:", "beta:start:"]
    again = car("sync", "--network-timeout", "5")
    assert again.returncode == 0 and "Sync: offline" in again.stdout


def test_a_pass_heals_drift_from_the_applied_revision_and_status_shows_the_agent(
    car: Lpam, fleet: RepoBuilder,
) -> None:
    import shutil

    assert car("sync").returncode == 0
    checkout = car.root / "var/lib/lpam/repositories/apps"
    shutil.rmtree(checkout)  # someone cleaned up the store behind lpam's back
    healed = car("sync")
    assert healed.returncode == 0 and "Sync: applied" in healed.stdout, healed.stderr
    assert checkout.is_dir()
    fleet.commit("typo", {"desired-state.yaml": "version: 1\naap: x\n"})
    fleet.push()
    assert car("sync").returncode == 1
    agent = car.status()["agent"]
    assert agent["vehicle"] == "rav4-07" and agent["last_attempt"]["result"] == "failed"
    assert agent["desired_revision"] == fleet.rev("HEAD") != agent["applied_revision"]
    table = car("status").stdout
    assert f"Agent (rav4-07): applied {agent['applied_revision'][:12]}" in table
    assert "last pass: failed" in table and "unknown key 'aap'" in table


def test_a_sync_killed_mid_install_is_finished_by_the_next_pass(
    car: Lpam, fleet: RepoBuilder, make_repo: Callable[[str], RepoBuilder],
) -> None:
    from tests.integration.apps import apps_repo

    apps_repo(make_repo("slow.git"), alpha={"install": "sleep 3"})
    fleet.commit("slow alpha", {"desired-state.yaml": fleet_state("alpha", MODE="one")
                                .replace("../apps.git", "../slow.git")})
    fleet.push()
    proc = car.spawn("sync")
    deadline = time.monotonic() + 60
    while "alpha:install:one" not in car.events() and time.monotonic() < deadline:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)  # lpam dies; its install.sh runs on under its guard
    proc.communicate(timeout=30)
    done = car("sync", "--lock-timeout", "30")  # waits for the orphaned install.sh
    assert done.returncode == 0, done.stdout + done.stderr
    assert car.events() == ["alpha:install:one", "alpha:start:one"]  # nothing ran twice
    assert status(car)["applied_revision"] == fleet.rev("HEAD")
