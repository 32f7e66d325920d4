"""Issue 34: a revision reaches the fleet in waves decided by evidence, with no controller.

Five car roots follow one fleet repository on a real `git daemon` (127.0.0.1); each runs
its apps as real processes under its own supervisord, and its agent's real passes
(workflow/sync.py) fetch, decide, apply and publish `status/<vehicle>`. Only the clock is
the test's: one clock for the five cars, moved on by the test, so the proof's ten minutes
take no time and every time asserted is exact.

The rollout: car-03 first, then car-01 and car-02, then everyone else. car-02 reports once
and then stays offline; the rollout skips a car silent for two hours.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import pytest

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from reconciler.core.documents import load_agent
from reconciler.workflow import fleet
from reconciler.workflow.events import Event, Note
from reconciler.workflow.fleetreport import write_report
from reconciler.workflow.machine import Machine
from reconciler.workflow.sync import Synced, sync
from schemas.timeline import Stamp
from tests.browser import PHONE, dom, png_size, screenshot
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import TICKER, processes
from tests.integration.several import running

CATALOG = """\
apps:
  - name: ctl-a
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0.3}
  - name: ctl-b
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0.3}
  - name: ctl-bad
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0.3, command: [./healthy.sh]}
"""

ROLLOUT = """\
rollout:
  waves: [[car-03], [car-01, car-02], ["*"]]
  prove_seconds: 600
  silent_seconds: 7200
"""

CARS = ("car-01", "car-02", "car-03", "car-04", "car-05")
START = datetime(2026, 11, 20, 6, 0, tzinfo=timezone.utc)


def desired(url: str, app: str, rollout: str = ROLLOUT) -> str:
    return (f"version: 2\nrepositories:\n  - url: {url}\napps:\n  - name: {app}\n"
            + rollout)


@dataclass
class Clock:
    now: datetime = START

    def __call__(self) -> datetime:
        return self.now


@dataclass
class Car:
    vehicle: str
    root: Path
    clock: Clock
    notes: list[str] = field(default_factory=list)

    def sync(self) -> Synced:
        layout = Layout(self.root)
        machine = Machine.at(layout, services="supervisor", network_timeout=30)
        machine.clock = self.clock
        # the boot's clock moves with the test's: one boot, started at START
        machine.stamp = lambda: Stamp(boot="boot-1", wall=self.clock.now,
                                      mono=(self.clock.now - START).total_seconds())

        def report(event: Event) -> None:
            if isinstance(event, Note):
                self.notes.append(event.text)

        return sync(machine, load_agent(layout.agent_config), report=report)

    def status(self) -> dict[str, Any]:
        found: dict[str, Any] = json.loads(
            (self.root / "var/lib/lpam/status.json").read_text())
        return found

    def runs(self) -> list[str]:
        return sorted(running(self.root))


@pytest.fixture
def world(make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
          tmp_path: Path) -> Iterator[tuple[RepoBuilder, str, dict[str, Car]]]:
    apps = make_repo("apps.git")
    apps.write("libpanda-apps.yaml", CATALOG)
    for app in ("ctl-a", "ctl-b", "ctl-bad"):
        apps.write(f"{app}/ticker.py", TICKER)
    apps.write("ctl-bad/healthy.sh", "#!/bin/sh\necho 'no CAN frames from the panda'\n"
               "exit 1\n", executable=True)
    apps.commit("three controllers")
    apps.push()
    url = git_daemon.url("apps.git")
    fleet_repo = make_repo("fleet.git")
    fleet_repo.commit("R1: ctl-a everywhere", {"desired-state.yaml": desired(url, "ctl-a",
                                                                            "")})
    fleet_repo.push()
    clock = Clock()
    cars = {}
    for vehicle in CARS:
        root = tmp_path / vehicle
        config = root / "etc/lpam/agent.yaml"
        config.parent.mkdir(parents=True)
        config.write_text(f"version: 1\nsource: {{url: {git_daemon.url('fleet.git')}, "
                          f"branch: main}}\nvehicle: {vehicle}\n")
        cars[vehicle] = Car(vehicle, root, clock)
    try:
        yield fleet_repo, url, cars
    finally:
        for car in cars.values():
            shutdown(Layout(car.root))
            for pid in processes(car.root):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)


def agent_rollout(car: Car) -> dict[str, Any]:
    found: dict[str, Any] = car.status()["rollout"]
    return found


def test_a_revision_goes_wave_by_wave_and_a_failed_canary_halts_the_rest(
        world: tuple[RepoBuilder, str, dict[str, Car]], git_daemon: GitDaemon,
        tmp_path: Path) -> None:
    repo, url, cars = world
    clock = next(iter(cars.values())).clock
    online = [cars[v] for v in ("car-03", "car-01", "car-04", "car-05")]

    for car in cars.values():  # R1 carries no rollout: every car takes it at once
        assert car.sync().result == "applied", car.notes
        assert car.runs() == ["ctl-a"]
    silent_since = clock.now  # car-02 reports now, then never again

    r2 = repo.commit("R2: ctl-b, in waves", {"desired-state.yaml": desired(url, "ctl-b")})
    repo.push()
    applied_at: dict[str, datetime] = {}

    def round_of_passes(minutes: int) -> None:
        clock.now += timedelta(minutes=minutes)
        for car in online:
            done = car.sync()
            if done.result == "applied":
                applied_at[car.vehicle] = clock.now

    round_of_passes(5)
    assert set(applied_at) == {"car-03"}  # the canary at once
    waiting = agent_rollout(cars["car-01"])
    assert (waiting["revision"], waiting["wave"], waiting["stage"]) == (r2, 2, "waiting")
    assert "waits for wave 1" in waiting["reason"] and "car-03" in waiting["reason"]
    assert cars["car-01"].runs() == ["ctl-a"]
    assert cars["car-01"].status()["last_attempt"]["result"] == "deferred"
    assert agent_rollout(cars["car-03"])["stage"] == "proving"

    for _ in range(4):  # 5 min passes: car-03 proves R2 ten minutes after it applied it
        round_of_passes(5)
    assert agent_rollout(cars["car-03"])["stage"] == "proven"
    assert "car-01" in applied_at and "car-04" not in applied_at
    assert applied_at["car-01"] - applied_at["car-03"] >= timedelta(seconds=600)
    assert cars["car-01"].runs() == ["ctl-b"]

    for _ in range(4):  # car-01 proves R2, but car-02 has been silent < 2 h: it holds
        round_of_passes(5)
    assert agent_rollout(cars["car-01"])["stage"] == "proven"
    assert "car-04" not in applied_at
    held = agent_rollout(cars["car-04"])
    assert held["wave"] == 3 and "car-02" in held["reason"], held

    clock.now = silent_since + timedelta(seconds=7200 - 60)  # a minute short of 2 h
    round_of_passes(0)
    assert "car-04" not in applied_at
    round_of_passes(1)  # car-02 is skipped once silent for 7,200 s
    assert "car-04" in applied_at
    assert applied_at["car-04"] - silent_since >= timedelta(seconds=7200)
    assert applied_at["car-04"] - applied_at["car-01"] >= timedelta(seconds=600)
    assert applied_at["car-05"] == applied_at["car-04"]
    assert cars["car-04"].runs() == ["ctl-b"]
    assert cars["car-02"].runs() == ["ctl-a"]  # it never saw R2

    r3 = repo.commit("R3: ctl-bad", {"desired-state.yaml": desired(url, "ctl-bad")})
    repo.push()
    for _ in range(6):  # an hour: the canary rolls back, nobody else ever takes R3
        round_of_passes(10)
    canary = cars["car-03"]
    assert canary.runs() == ["ctl-b"]
    assert agent_rollout(canary)["stage"] == "rolled back"
    assert agent_rollout(canary)["revision"] == r3
    for vehicle in ("car-01", "car-04", "car-05"):
        assert cars[vehicle].runs() == ["ctl-b"], vehicle
        halt = agent_rollout(cars[vehicle])
        assert halt["stage"] == "halted" and halt["revision"] == r3, halt
        assert "car-03 (wave 1) rolled back" in halt["reason"], halt
        assert cars[vehicle].status()["applied_revision"] == r2

    # the fleet's view says the same, from a clone of the fleet repository alone
    clone = tmp_path / "laptop-clone"
    subprocess.run(["git", "clone", "--quiet", git_daemon.url("fleet.git"), str(clone)],
                   env=repo.env, check=True, capture_output=True)
    tip, rows = fleet.read(clone)
    states = {row.vehicle: fleet.state_of(row, clock.now, silent=7200) for row in rows}
    assert tip == r3
    assert states["car-03"][0] == "rolled back"
    assert states["car-01"][0] == "waiting" and "halted" in states["car-01"][1]
    assert states["car-02"][0] == "unknown"

    # and so does the report, opened in a browser as a lab manager would
    page = write_report(clone, tmp_path / "report", now=clock.now)
    built = dom(page, tmp_path / "browser")
    shown = {vehicle: re.sub(r"<[^>]+>", " ", row) for vehicle, row in re.findall(
        r'<tr id="car-([\w-]+)" data-state="[^"]+">(.*?)</tr>', built, re.S)}
    assert set(shown) == set(CARS)
    assert "rolled back" in shown["car-03"] and "halted: car-03" in shown["car-01"]
    assert "unknown" in shown["car-02"] and "waiting" in shown["car-04"]
    assert "a halted rollout" in shown["car-04"]  # what it waits for, in a few words
    canary_line = re.search(r'<svg [^>]*data-vehicle="car-03">.*?</svg>', built, re.S)
    assert canary_line is not None
    assert 'data-kind="ran"' in canary_line.group(0)  # from its published timeline
    assert re.search(r'data-kind="rollback"><title>[^<]*ctl-bad: its health check '
                     r'`./healthy.sh` failed', canary_line.group(0)), canary_line.group(0)
    assert "<dt>Rollout</dt><dd>waves car-03 → car-01, car-02 → *" in built
    assert png_size(screenshot(page, tmp_path / "browser"))[0] == PHONE[0]

    # the lab reverts R3 in git: that is the fleet's rollback, and no wave holds it
    repo.commit("Revert R3", {"desired-state.yaml": desired(url, "ctl-b")})
    repo.push()
    round_of_passes(5)
    for car in online:
        assert car.status()["last_attempt"]["result"] in ("applied", "nothing to do"), \
            car.notes
        assert car.runs() == ["ctl-b"]
