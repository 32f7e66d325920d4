"""`lpam agent`: sync passes forever with jitter and backoff, stopped by SIGTERM — at once
between passes, and during a pass only before its cutover, never in the middle of one.
Real git daemon, real CLI process for the signal, the Agent use case for the timing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

import pytest

from reconciler.base.layout import Layout
from reconciler.core.documents import load_agent
from reconciler.workflow.agent import Agent, next_wait
from reconciler.workflow.applying import ApplyOptions
from reconciler.workflow.events import Event, Progress
from reconciler.workflow.machine import Machine
from tests.contract.test_services import wait_for
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.conftest import fleet_state


def test_waits_grow_after_failures_up_to_a_cap_with_jitter() -> None:
    assert next_wait(300, 0, 0.5) == pytest.approx(300)
    assert next_wait(300, 0, 0.0) == pytest.approx(270)
    assert next_wait(300, 0, 0.999) == pytest.approx(330, rel=1e-3)
    assert [next_wait(300, n, 0.5) for n in (1, 2, 3, 4, 9)] == pytest.approx(
        [600, 1200, 2400, 2400, 2400])


class Clocked(Agent):
    """An agent whose waits are recorded instead of slept; it stops after `waits` waits."""

    waited: list[float]
    limit: int = 2

    def wait(self, seconds: float) -> bool:
        self.waited.append(seconds)
        if len(self.waited) >= self.limit:
            self.stop.set()
        return self.stop.is_set()


def agent_for(car: Lpam, report: Callable[[Event], None] = lambda e: None) -> Clocked:
    layout = Layout(car.root)
    machine = Machine.at(layout, services="supervisor", network_timeout=10)
    agent = Clocked(machine, load_agent(layout.agent_config), report=report, draw=lambda: 0.5)
    agent.waited = []
    return agent


def test_failed_passes_back_off_and_a_good_one_resets_the_wait(
    car: Lpam, fleet: RepoBuilder,
) -> None:
    fleet.commit("typo", {"desired-state.yaml": "version: 1\naap: x\n"})
    fleet.push()
    agent = agent_for(car)
    agent.limit = 2
    assert agent.run() == 0
    # the broken revision failed once, then was not retried (nothing to do): one doubling
    assert [p.result for p in agent.passes] == ["failed", "nothing to do"]
    assert agent.waited == [600, 300]


def test_a_stop_during_preparation_stops_before_the_cutover_and_the_next_run_resumes(
    car: Lpam, fleet: RepoBuilder,
) -> None:
    agent: Clocked

    def stop_at_first_step(event: Event) -> None:
        if isinstance(event, Progress) and event.text.startswith("[1/"):
            agent.stop.set()  # SIGTERM while the first preparation step runs

    agent = agent_for(car, stop_at_first_step)
    assert agent.run() == 0
    assert [p.result for p in agent.passes] == ["stopped"]
    assert car.events() == []  # nothing installed: stopped before the cutover
    again = car("sync")
    assert again.returncode == 0 and "Sync: applied" in again.stdout
    assert car.events() == ["alpha:install:one", "alpha:start:one"]


def test_a_stop_during_the_cutover_lets_it_finish(car: Lpam, fleet: RepoBuilder) -> None:
    agent: Clocked

    def stop_in_cutover(event: Event) -> None:
        if isinstance(event, Progress) and "install:" in event.text:
            agent.stop.set()

    agent = agent_for(car, stop_in_cutover)
    assert agent.run() == 0
    assert [p.result for p in agent.passes] == ["applied"]
    assert car.events() == ["alpha:install:one", "alpha:start:one"]


def test_sigterm_between_passes_stops_the_agent_process_at_once(
    car: Lpam, fleet: RepoBuilder, tmp_path: Path,
) -> None:
    config = car.root / "etc/lpam/agent.yaml"
    config.write_text(config.read_text() + "interval_seconds: 600\n")
    output = tmp_path / "agent.out"
    with output.open("w") as sink:
        proc = subprocess.Popen([sys.executable, "-m", "reconciler", "--root", str(car.root),
                                 "agent"], stdout=sink, stderr=subprocess.STDOUT,
                                text=True, env=dict(os.environ), start_new_session=True)
    try:
        status = car.root / "var/lib/lpam/status.json"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (
                status.exists() and json.loads(status.read_text()).get("applied_revision")):
            time.sleep(0.2)
        assert status.exists(), "the first pass did not finish"
        # into the 10-minute wait: the agent says so just before it begins
        assert wait_for(lambda: "next pass in" in output.read_text(), 60), output.read_text()
        started = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
        out = output.read_text()
        assert proc.returncode == 0, out
        assert time.monotonic() - started < 10
        assert "next pass in" in out and "agent stopped" in out
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert car.events() == ["alpha:install:one", "alpha:start:one"]


def test_agent_once_is_one_pass_with_its_exit_code(car: Lpam, fleet: RepoBuilder) -> None:
    done = car("agent", "--once")
    assert done.returncode == 0, done.stdout + done.stderr
    assert car.events() == ["alpha:install:one", "alpha:start:one"]
    fleet.commit("typo", {"desired-state.yaml": "version: 1\naap: x\n"})
    fleet.push()
    assert car("agent", "--once").returncode == 1


@pytest.fixture(autouse=True)
def _daemon(git_daemon: GitDaemon) -> None:
    """Every test here talks to the fleet's daemon."""


def test_a_deferred_pass_is_no_failure_and_the_next_pass_tries_again(
    car: Lpam, fleet: RepoBuilder,
) -> None:
    first = agent_for(car)
    first.limit = 1
    assert first.run() == 0 and first.passes[0].result == "applied"
    later = (datetime.now().astimezone().hour + 2) % 24
    window = f"{later:02d}:00-{(later + 1) % 24:02d}:00"  # closed now
    fleet.commit("beta, at night only", {"desired-state.yaml": fleet_state("beta") + (
        f"gates: {{on_no_signal: allow, windows: ['{window}']}}\n")})
    fleet.push()
    layout = Layout(car.root)
    agent = Clocked.following(Machine.at(layout, services="supervisor", network_timeout=10),
                              load_agent(layout.agent_config), options=ApplyOptions(),
                              report=lambda e: None)  # as `lpam agent` makes it
    assert isinstance(agent, Clocked)
    agent.draw, agent.waited = lambda: 0.5, []
    assert agent.run() == 0
    assert [p.result for p in agent.passes] == ["deferred", "deferred"]  # tried again
    assert agent.waited == [300, 300]  # no backoff
    shown = car("status").stdout  # deferred, with when the next pass tries (issue 30)
    assert "Last apply: deferred at" in shown and "outside" in shown, shown
    assert "the agent's next pass tries again at about" in shown
    assert car.status()["last_apply"]["retry"] is not None
    done = car("sync")
    assert done.returncode == 75 and "outside" in done.stderr, done.stderr
    status = car.status()
    assert status["last_apply"]["state"] == "deferred"
    assert status["last_apply"]["retry"] is None  # a pass of its own: nothing tries again
    assert car("agent", "--once").returncode == 75  # one pass: no next one either
    assert car.status()["last_apply"]["retry"] is None
    assert status["agent"]["last_attempt"]["result"] == "deferred"
    assert status["app"]["name"] == "alpha" and status["app"]["running"] is True
