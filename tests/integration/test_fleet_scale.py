"""The fleet at scale (issue 18, item 8): what each agent pass costs the fleet repository.

A real `git daemon` on 127.0.0.1 logs every connection (`--verbose`: one "Request
upload-pack" per ref advertisement, one "Request receive-pack" per push), and the bare
repository says how many commits each status branch holds. The agent runs its real
passes; only its clock is injected (each wait moves it on by the wait, the heartbeat by
hours), so nothing here depends on how fast this machine is.

What it shows: a pass that changed nothing is one ref advertisement and no push; a status
is pushed when it changed or when the heartbeat is due; a status branch never holds more
than `HISTORY` commits; a read-only fleet repository costs a plain note and no retry at
every pass.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import pytest

from reconciler.base.layout import Layout
from reconciler.core.documents import load_agent
from reconciler.core.publication import HISTORY
from reconciler.workflow.agent import Agent
from reconciler.workflow.events import Event, Note
from reconciler.workflow.machine import Machine
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.conftest import fleet_state, following

VEHICLE = "rav4-07"
BRANCH = f"refs/heads/status/{VEHICLE}"


@pytest.fixture
def git_daemon(tmp_path_factory: pytest.TempPathFactory, hermetic_env: Path) -> Iterator[GitDaemon]:
    """The fleet's daemon (it accepts pushes), logging every connection."""
    log = tmp_path_factory.mktemp("daemon-log") / "daemon.log"
    with GitDaemon(tmp_path_factory.mktemp("served"), home=hermetic_env, log=log,
                   receive_pack=True) as daemon:
        yield daemon


@pytest.fixture
def pinned(fleet: RepoBuilder, apps: str) -> RepoBuilder:
    """The fleet's desired state with the app's commit pinned (as `lpam pin` leaves it), so
    that a pass needs the network for the fleet repository alone."""
    fleet.commit("pin the apps", {"desired-state.yaml": fleet_state("alpha", pin=apps,
                                                                     MODE="one")})
    fleet.push()
    return fleet


def requests(daemon: GitDaemon) -> list[str]:
    """Every request the daemon served so far, as `service repository`."""
    assert daemon.log is not None
    return [line.split("] Request ", 1)[1].replace(" for ", " ").replace("'", "")
            for line in daemon.log.read_text().splitlines() if "] Request " in line]


def commits(daemon: GitDaemon, ref: str = BRANCH) -> int:
    """How many commits `ref` of the served fleet repository holds (0 without it)."""
    done = subprocess.run(["git", "--git-dir", str(daemon.base / "fleet.git"), "rev-list",
                           "--count", ref, "--"], capture_output=True, text=True,
                          env={"HOME": str(daemon.base), "PATH": "/usr/bin:/bin"})
    return int(done.stdout.strip()) if done.returncode == 0 else 0


@dataclass
class Clock:
    """The agent's clock, moved on by the test instead of by time."""

    now: datetime = datetime(2026, 11, 20, 6, 0, tzinfo=timezone.utc)

    def __call__(self) -> datetime:
        return self.now


@dataclass
class Pass:
    """What one pass asked of the daemon, and the status branch after it."""

    result: str
    asked: list[str]
    commits: int


class Counted(Agent):
    """An agent whose waits move its clock on instead of sleeping; after each pass it
    records what the daemon served, runs `between(n)` (n passes done) and stops after
    `limit` passes."""

    clock: Clock
    daemon: GitDaemon
    limit: int
    between: Callable[[int], None]
    seen: list[Pass]

    def wait(self, seconds: float) -> bool:
        self.clock.now += timedelta(seconds=seconds)
        return self._count()

    def _count(self) -> bool:
        served = requests(self.daemon)
        before = sum(len(p.asked) for p in self.seen)
        self.seen.append(Pass(self.passes[-1].result, served[before:], commits(self.daemon)))
        if len(self.seen) >= self.limit:
            self.stop.set()
        else:
            self.between(len(self.seen))
        return self.stop.is_set()


@dataclass
class Car:
    lpam: Lpam
    clock: Clock = field(default_factory=Clock)
    notes: list[str] = field(default_factory=list)

    def agent(self, daemon: GitDaemon, limit: int,
              between: Callable[[int], None] = lambda n: None) -> Counted:
        layout = Layout(self.lpam.root)
        machine = Machine.at(layout, services="supervisor", network_timeout=30)
        machine.clock = self.clock

        def report(event: Event) -> None:
            if isinstance(event, Note):
                self.notes.append(event.text)

        agent = Counted(machine, load_agent(layout.agent_config), report=report,
                        draw=lambda: 0.5)  # no jitter: every wait is the interval
        agent.clock, agent.daemon, agent.limit = self.clock, daemon, limit
        agent.between, agent.seen = between, []
        return agent

    def status(self) -> dict[str, Any]:
        found: dict[str, Any] = json.loads(
            (self.lpam.root / "var/lib/lpam/status.json").read_text())
        return found


@pytest.fixture
def car(tmp_path: Path, git_daemon: GitDaemon) -> Car:
    return Car(following(tmp_path / "root", git_daemon.url("fleet.git"), VEHICLE))


FETCH = "upload-pack /fleet.git"
PUSH = "receive-pack /fleet.git"


def test_ten_passes_push_only_a_changed_status_or_the_heartbeat(
    car: Car, pinned: RepoBuilder, apps: str, git_daemon: GitDaemon,
) -> None:
    def between(done: int) -> None:
        if done == 4:  # the lab changes the fleet's parameters: pass 5 applies them
            pinned.commit("mode two", {"desired-state.yaml": fleet_state(
                "alpha", pin=apps, MODE="two")})
            pinned.push()
        if done == 7:  # the car stood quiet for six hours: pass 8 is the heartbeat
            car.clock.now += timedelta(hours=6)

    agent = car.agent(git_daemon, limit=10, between=between)
    assert agent.run() == 0
    seen = agent.seen
    assert [p.result for p in seen] == ["applied", *["nothing to do"] * 3, "applied",
                                        *["nothing to do"] * 5]
    # the first pass also clones the app repository it pins; no other pass asks it anything
    assert seen[0].asked == [FETCH, "upload-pack /apps.git", PUSH]
    pushed = [n for n, p in enumerate(seen, 1) if PUSH in p.asked]
    assert pushed == [1, 5, 8]  # first report, a change, the heartbeat
    for number, done in enumerate(seen[1:], 2):
        expected = [FETCH, PUSH] if number in pushed else [FETCH]
        assert done.asked == expected, f"pass {number}: {done.asked}"
    assert [p.commits for p in seen] == [1, 1, 1, 1, 2, 2, 2, 3, 3, 3]
    assert car.notes == []
    published = car.status()["publication"]
    assert published["result"] == "pushed"
    assert published["time"] == "2026-11-20T12:35:00+00:00"  # pass 8: 7 waits and 6 h on


def test_a_status_branch_never_holds_more_than_its_bound(
    car: Car, pinned: RepoBuilder, git_daemon: GitDaemon,
) -> None:
    agent = car.agent(git_daemon, limit=HISTORY + 2,
                      between=lambda n: setattr(car.clock, "now",
                                                car.clock.now + timedelta(hours=6)))
    assert agent.run() == 0
    assert all(PUSH in p.asked for p in agent.seen)  # every pass a heartbeat
    assert [p.commits for p in agent.seen] == [*range(1, HISTORY + 1), 1, 2]
    assert car.notes == []  # the daemon took the rewrite of the car's own branch
    body = json.loads(subprocess.run(
        ["git", "--git-dir", str(git_daemon.base / "fleet.git"), "show",
         f"{BRANCH}:status.json"], capture_output=True, text=True, check=True).stdout)
    assert body["agent"]["vehicle"] == VEHICLE and body["app"]["name"] == "alpha"


def test_a_repository_that_refuses_rewrites_gets_the_status_on_top(
    car: Car, pinned: RepoBuilder, git_daemon: GitDaemon,
) -> None:
    subprocess.run(["git", "--git-dir", str(git_daemon.base / "fleet.git"), "config",
                    "receive.denyNonFastForwards", "true"], check=True)
    agent = car.agent(git_daemon, limit=HISTORY + 1,
                      between=lambda n: setattr(car.clock, "now",
                                                car.clock.now + timedelta(hours=6)))
    assert agent.run() == 0
    assert [p.commits for p in agent.seen] == list(range(1, HISTORY + 2))
    assert agent.seen[-1].asked == [FETCH, PUSH, PUSH]  # refused, then on top
    assert len(car.notes) == 1 and "allow non-fast-forward pushes" in car.notes[0]
    assert car.status()["publication"]["result"] == "pushed"


def test_a_read_only_fleet_repository_costs_a_plain_note_and_no_push_every_pass(
    tmp_path: Path, pinned: RepoBuilder, git_daemon: GitDaemon, hermetic_env: Path,
) -> None:
    log = tmp_path / "read-only.log"
    with GitDaemon(git_daemon.base, home=hermetic_env, log=log) as read_only:
        lpam = following(tmp_path / "car", read_only.url("fleet.git"), VEHICLE)
        first = lpam("sync")
        assert first.returncode == 0, first.stderr
        assert "Sync: applied" in first.stdout
        note = " ".join(first.stderr.split())
        assert "does not accept pushes from this machine" in note
        assert "read-only for this car" in note and "The car keeps working" in note
        assert "status stays local" in note
        again = lpam("sync")
        assert again.returncode == 0 and "Sync: nothing to do" in again.stdout
        assert "status not published" not in again.stderr  # not asked again every pass
        assert requests(read_only) == [FETCH, "upload-pack /apps.git", PUSH, FETCH]
    status = json.loads((lpam.root / "var/lib/lpam/status.json").read_text())
    assert status["publication"]["result"] == "refused"
    assert status["follows"] == "desired-state.yaml"
    assert commits(git_daemon) == 0
