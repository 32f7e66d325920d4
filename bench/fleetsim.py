"""A fleet of car agents against one loopback git server: a revision in waves, a rollback
in wave 2, the lab's revert — with every connection and byte the server sees.

    python -m bench.fleetsim --cars 100

Each car is a root of its own with its real agent pass (workflow/sync.py: fetch, the
waves' decision, apply, publish `status/<vehicle>`); its service manager is the in-memory
twin (adapters/services/memory.py), so a hundred cars need no hundred supervisords, while
the health check is the app's real script. One clock for all, moved on by the simulation,
so proof windows take no time. All git traffic passes a counting relay (bench/relay.py)
in front of one `git daemon` on 127.0.0.1.

The rollout: car-001 first, then wave 2 (a tenth of the fleet, at least two cars), then
everyone. R2's health check fails on one car of wave 2 (a file in its root says so): the
later waves must never take R2. Then the lab reverts R2 in git and every car returns to
R1 in one round, no wave holding it.

`simulate` is what tests/integration/test_fleet_sim.py runs with a few cars.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from bench.relay import Relay, Traffic
from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.layout import Layout
from reconciler.core.documents import load_agent
from reconciler.workflow.events import Event
from reconciler.workflow.machine import Machine
from reconciler.workflow.sync import sync
from schemas.timeline import Stamp
from tests.gitserver import GitDaemon, RepoBuilder

CATALOG = """\
apps:
  - name: ctl-a
    command: [python3, -u, ctl.py]
    health: {settle_seconds: 0}
  - name: ctl-b
    command: [python3, -u, ctl.py]
    health: {settle_seconds: 0, command: [./healthy.sh]}
"""

HEALTHY = """#!/bin/sh
if [ -e "$LPAM_ROOT/broken" ]; then echo 'no CAN frames on this car'; exit 1; fi
"""

INTERVAL = timedelta(minutes=5)
PROVE = 600


@dataclass
class Clock:
    now: datetime = datetime(2026, 11, 20, 6, 0, tzinfo=timezone.utc)

    def __call__(self) -> datetime:
        return self.now


@dataclass
class Car:
    vehicle: str
    machine: Machine
    applied: dict[str, datetime] = field(default_factory=dict)  # revision -> when

    def status(self) -> dict[str, Any]:
        found: dict[str, Any] = json.loads(self.machine.layout.agent_status.read_text())
        return found


@dataclass
class Phase:
    name: str
    rounds: int
    passes: int
    traffic: Traffic
    seconds: float
    stages: dict[str, dict[str, Any] | None]  # each car's rollout state at the phase's end


@dataclass
class Outcome:
    cars: dict[str, Car]
    waves: list[list[str]]
    broken: str
    revisions: dict[str, str]  # R1, R2, R3 -> commit
    phases: list[Phase]


def desired(url: str, pin: str, app: str, rollout: str) -> str:
    return (f"version: 2\nrepositories:\n  - url: {url}\n    ref: {pin}\napps:\n"
            f"  - name: {app}\n{rollout}")


def simulate(count: int, work: Path, *, home: Path, max_rounds: int = 12) -> Outcome:
    """Run the story with `count` cars under `work` (`home`: git's HOME)."""
    names = [f"car-{n:03d}" for n in range(1, count + 1)]
    second = names[1:1 + max(2, count // 10)]
    broken = second[len(second) // 2]
    waves = [names[:1], second, ["*"]]
    rollout = ("rollout:\n  waves: " + json.dumps(waves) +
               f"\n  prove_seconds: {PROVE}\n  silent_seconds: 7200\n")
    clock = Clock()
    phases: list[Phase] = []
    with GitDaemon(work / "served", home=home, receive_pack=True) as daemon, \
            Relay(daemon.port) as relay:
        apps = RepoBuilder(daemon.base, "apps.git", work_root=work / "w", home=home)
        apps.write("libpanda-apps.yaml", CATALOG)
        for app in ("ctl-a", "ctl-b"):
            apps.write(f"{app}/ctl.py", "import time\nwhile True: time.sleep(1)\n")
        apps.write("ctl-b/healthy.sh", HEALTHY, executable=True)
        pin = apps.commit("two controllers")
        apps.push()
        url = relay.url("apps.git")
        fleet = RepoBuilder(daemon.base, "fleet.git", work_root=work / "w", home=home)
        r1 = fleet.commit("R1: ctl-a", {"desired-state.yaml": desired(url, pin, "ctl-a", "")})
        fleet.push()
        cars = {name: _car(work / "cars" / name, name, relay.url("fleet.git"), clock)
                for name in names}
        (cars[broken].machine.layout.root / "broken").write_text("no CAN frames\n")

        def rounds(name: str, done: Callable[[], bool]) -> None:
            mark, began, passes, count_rounds = relay.mark(), time.perf_counter(), 0, 0
            while count_rounds < max_rounds:
                count_rounds += 1
                for car in cars.values():
                    result = sync(car.machine, load_agent(car.machine.layout.agent_config),
                                  report=_quiet)
                    passes += 1
                    if result.result == "applied" and result.revision is not None:
                        car.applied[result.revision] = clock.now
                if done():
                    break
                clock.now += INTERVAL
            phases.append(Phase(name, count_rounds, passes, relay.since(mark),
                                time.perf_counter() - began,
                                {n: c.status().get("rollout") for n, c in cars.items()}))

        rounds("R1 to every car (no rollout)", lambda: all(r1 in c.applied
                                                            for c in cars.values()))
        clock.now += timedelta(hours=1)
        r2 = fleet.commit("R2: ctl-b in waves", {"desired-state.yaml": desired(
            url, pin, "ctl-b", rollout)})
        fleet.push()
        rest = [c for n, c in cars.items() if n not in second and n != names[0]]
        rounds("R2 in waves, rolled back in wave 2",
               lambda: bool(rest) and all(_stage(c, r2) == "halted" for c in rest)
               and all(_stage(cars[n], r2) in ("proving", "proven", "rolled back")
                       for n in second))
        clock.now += INTERVAL
        r3 = fleet.commit("Revert R2", {"desired-state.yaml": desired(url, pin, "ctl-a", "")})
        fleet.push()
        rounds("the revert, to every car", lambda: all(
            c.status()["applied_revision"] == r3 for c in cars.values()))
    return Outcome(cars, waves, broken, {"R1": r1, "R2": r2, "R3": r3}, phases)


def _car(root: Path, vehicle: str, url: str, clock: Clock) -> Car:
    config = root / "etc/lpam/agent.yaml"
    config.parent.mkdir(parents=True)
    config.write_text(f"version: 1\nsource: {{url: {url}, branch: main}}\n"
                      f"vehicle: {vehicle}\n")
    machine = Machine(Layout(root), given_services=MemoryServices(), network_timeout=30)
    machine.clock = clock
    start = clock.now  # the boot's clock moves with the simulation's: one boot each
    machine.stamp = lambda: Stamp(boot=f"boot-{vehicle}", wall=clock.now,
                                  mono=(clock.now - start).total_seconds())
    return Car(vehicle, machine)


def _stage(car: Car, revision: str) -> str | None:
    rollout = car.status().get("rollout")
    return None if rollout is None or rollout["revision"] != revision else \
        str(rollout["stage"])


def _quiet(event: Event) -> None:
    pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cars", type=int, default=100)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        home = Path(tmp) / "home"
        home.mkdir()
        done = simulate(args.cars, Path(tmp), home=home)
    r2 = done.revisions["R2"]
    took = sorted((c.applied[r2], n) for n, c in done.cars.items() if r2 in c.applied)
    print(f"{args.cars} cars; waves: {done.waves[0]} | {len(done.waves[1])} cars | the rest; "
          f"R2's health check fails on {done.broken}")
    print(f"R2 reached {len(took)} cars: " + ", ".join(
        f"{n} at +{(t - took[0][0]).total_seconds() / 60:.0f} min" for t, n in took))
    print("\n| phase | rounds | passes | connections | bytes to the cars | bytes from the "
          "cars | per pass | seconds (this machine) |\n|---|---:|---:|---:|---:|---:|---:|---:|")
    for phase in done.phases:
        t = phase.traffic
        print(f"| {phase.name} | {phase.rounds} | {phase.passes} | {t.connections} | "
              f"{t.to_client / 1024:.0f} KiB | {t.to_server / 1024:.0f} KiB | "
              f"{t.connections / phase.passes:.2f} conn, "
              f"{(t.to_client + t.to_server) / phase.passes / 1024:.1f} KiB | "
              f"{phase.seconds:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
