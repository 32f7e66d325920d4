"""Random faults at random instants of every kind of change, with the bus sampled all along.

The probe of issue 17, kept: apps under a real supervisord that hold the CAN bus (an
exclusive `flock`; a copy that finds it taken writes `collisions.log`), driven by the real
`lpam` through switches, parameter changes, new commits, a switch to an app that fails its
health check, `lpam rollback`, `lpam stop` and `lpam start`. At a random instant of each
command one fault lands: SIGKILL of lpam's whole session, SIGINT or SIGTERM of lpam, or
`kill -9` of supervisord. A sampler looks at the app processes every 50 ms the whole time.
After each round a plain `lpam apply` recovers, and what `lpam status` says must be what
runs: the app it names running (and nothing else) when it says running, nothing when it
says stopped.

Violations counted: two app processes alive at once (sampled), a collision on the bus, a
status that is not what runs, an internal error or a traceback, a recovery that did not
converge. The normal run tries a few rounds; `LPAM_FAULT_ROUNDS=200` tries many (the
figures in docs/reliability.md). The seed is fixed, so a failure replays.
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.test_fault_truth import BUS, CATALOG, apps_running, bus_holders
from tests.lengths import knob

ROUNDS = knob("LPAM_FAULT_ROUNDS", 6, 200)  # LPAM_LONG=1: 200 (tests/lengths.py)
SEED = int(os.environ.get("LPAM_FAULT_SEED", "17"))
CHANGES = ("switch", "params", "commit", "failing", "rollback", "stop", "start")
FAULTS = ("SIGKILL", "SIGINT", "SIGTERM", "kill -9 supervisord")


def state(url: str, app: str, mode: str) -> str:
    return (f"version: 1\nrepositories:\n  - url: {url}\napp:\n  name: {app}\n"
            f"  params: {{MODE: \"{mode}\"}}\n")


@dataclass
class Sampler:
    """Counts the app processes every 50 ms; more than one alive is two owners."""

    root: Path
    violations: list[str] = field(default_factory=list)
    samples: int = 0
    _stop: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:
        while not self._stop.wait(0.05):
            alive = bus_holders(self.root)
            self.samples += 1
            if len(alive) > 1:
                self.violations.append(f"two owners sampled: {describe(alive)}")

    @contextlib.contextmanager
    def watching(self) -> Iterator[None]:
        thread = threading.Thread(target=self.run, daemon=True)
        thread.start()
        try:
            yield
        finally:
            self._stop.set()
            thread.join(timeout=10)


def describe(pids: list[int]) -> str:
    """pid, parent and app of each process, for the report."""
    out = []
    for pid in pids:
        with contextlib.suppress(OSError):
            stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            env = dict(item.split(b"=", 1) for item in
                       Path(f"/proc/{pid}/environ").read_bytes().split(b"\0") if b"=" in item)
            out.append(f"{pid} (parent {stat[1]}, {env.get(b'LPAM_APP', b'?').decode()})")
    return ", ".join(out)


def supervisord(root: Path) -> int | None:
    with contextlib.suppress(OSError, ValueError):
        pid = int((root / "run/lpam/supervisord.pid").read_text())
        os.kill(pid, 0)
        return pid
    return None


def truthful(lpam: Lpam) -> str | None:
    """None when `lpam status` says what runs; else what differs."""
    time.sleep(1.2)  # supervisord's startsecs: a copy that could not start has gone
    status = lpam.status()
    running = apps_running(lpam.root)
    app = status["app"]
    said = [app["name"]] if app is not None and app["running"] else []
    if said != running:
        return f"status says {said} running, {running} runs"
    return None


def test_random_faults_never_give_two_owners_and_status_tells_the_truth(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("bus.git")
    repo.write("libpanda-apps.yaml", CATALOG)
    for app in ("steady", "other", "failing"):
        repo.write(f"{app}/bus.py", BUS)
    repo.write("failing/healthy.sh", "#!/bin/sh\nexit 1\n", executable=True)
    repo.commit("apps that hold the bus")
    repo.push()
    url = git_daemon.url("bus.git")
    rng = random.Random(SEED)
    sampler = Sampler(lpam.root)
    wanted, mode = "steady", "0"
    lpam.desired(state(url, wanted, mode))
    assert lpam("apply", "--yes").returncode == 0
    landed = 0
    problems: list[str] = []
    with sampler.watching():
        for round_ in range(ROUNDS):
            change = CHANGES[round_ % len(CHANGES)] if round_ < len(CHANGES) \
                else rng.choice(CHANGES)
            command = ["apply", "--yes", "--lock-timeout", "60"]
            if change == "switch":
                wanted = "other" if wanted == "steady" else "steady"
            elif change == "params":
                mode = str(round_)
            elif change == "commit":
                repo.write(f"{wanted}/VERSION", f"{round_}\n")
                repo.commit(f"{wanted} {round_}")
                repo.push()
            elif change == "rollback":
                command = ["rollback", "--yes", "--lock-timeout", "60"]
            elif change in ("stop", "start"):
                command = [change, "--lock-timeout", "60"]
            desired_app = "failing" if change == "failing" else wanted
            lpam.desired(state(url, desired_app, mode))
            fault = rng.choice(FAULTS)
            proc = lpam.spawn(*command)
            time.sleep(rng.uniform(0.0, 3.0))
            if proc.poll() is None:
                landed += 1
                if fault == "kill -9 supervisord":
                    pid = supervisord(lpam.root)
                    if pid is not None:
                        os.kill(pid, signal.SIGKILL)
                elif fault == "SIGKILL":
                    os.killpg(proc.pid, signal.SIGKILL)
                else:
                    os.kill(proc.pid, getattr(signal, fault))
            _, err = proc.communicate(timeout=180)
            where = f"round {round_} ({change}, {fault})"
            if "internal error" in err or ("Traceback" in err and "KeyboardInterrupt"
                                           not in err):
                problems.append(f"{where}: {err}")
            lpam.desired(state(url, wanted, mode))  # the failing app is not wanted again
            done = lpam("apply", "--yes", "--lock-timeout", "60")
            if done.returncode not in (0, 3) or "internal error" in done.stderr:
                problems.append(f"{where}: recovery exit {done.returncode}: {done.stderr}")
            again = lpam("apply", "--yes", "--lock-timeout", "60")  # a rollback finished
            if again.returncode != 0:
                problems.append(f"{where}: no convergence: {again.stderr}")
            lie = truthful(lpam)
            if lie is not None:
                problems.append(f"{where}: {lie}")
            if (lpam.root / "collisions.log").exists():
                problems.append(f"{where}: collisions {(lpam.root / 'collisions.log').read_text()}")
                (lpam.root / "collisions.log").unlink()
    problems += sampler.violations
    print(f"\n{ROUNDS} rounds, {landed} faults landed mid-command, {sampler.samples} samples "
          f"of the bus, {len(problems)} violations")
    assert landed > 0 and sampler.samples > 0
    assert problems == [], "\n".join(problems)
