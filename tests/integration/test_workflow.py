"""The use cases every caller shares (the CLI, and the agent and Bluetooth service after
it), driven directly: they report what they do as events and print nothing; a declined
plan changes nothing; a plan reports its phases in order."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from reconciler.engine.records.state import read_record
from reconciler.workflow.applying import ApplyOptions, apply
from reconciler.workflow.events import Event, Phase, Planned, Progress
from reconciler.workflow.machine import Machine
from reconciler.workflow.planning import plan
from schemas.plan import Plan
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import apps_repo, desired


@pytest.fixture
def machine(tmp_path: Path) -> Iterator[Machine]:
    layout = Layout(tmp_path / "root")
    try:
        yield Machine.at(layout, services="supervisor", network_timeout=30)
    finally:
        shutdown(layout)


@pytest.fixture
def document(machine: Machine, make_repo: Callable[[str], RepoBuilder],
             git_daemon: GitDaemon) -> Path:
    apps_repo(make_repo("apps.git"))
    path = machine.layout.desired_state
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(desired(git_daemon.url("apps.git"), "alpha", MODE="fast"))
    return path


def test_apply_reports_its_plan_then_each_step_and_prints_nothing(
    machine: Machine, document: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    from reconciler.core.documents import load_desired

    events: list[Event] = []
    done = apply(machine, document, load_desired(document), options=ApplyOptions(),
                 confirm=lambda made: True, report=events.append)
    assert capsys.readouterr() == ("", "")  # a use case never prints
    assert isinstance(events[0], Phase) and events[0].name == "resolve"
    planned = next(e for e in events if isinstance(e, Planned))
    steps = [e.text for e in events if isinstance(e, Progress)]
    assert steps == [f"[{n}/{len(planned.plan.steps)}] {s.id} …"
                     for n, s in enumerate(planned.plan.steps, 1)]
    assert done.steps == len(planned.plan.steps) and \
        done.app.startswith("alpha unverified: recorded running")  # its unit is its own
    assert (machine.layout.root / "events.log").read_text().split() == [
        "alpha:install:fast", "alpha:start:fast"]


def test_a_declined_plan_changes_nothing(machine: Machine, document: Path) -> None:
    from reconciler.core.documents import load_desired

    seen: list[Plan] = []

    def decline(made: Plan) -> bool:
        seen.append(made)
        return False

    done = apply(machine, document, load_desired(document), options=ApplyOptions(),
                 confirm=decline, report=lambda e: None)
    assert done.cancelled and done.steps == 0 and seen[0].steps
    assert not read_record(machine.layout).apps
    assert not (machine.layout.root / "events.log").exists()


def test_a_plan_reports_its_phases_in_order(machine: Machine, document: Path) -> None:
    from reconciler.core.documents import load_desired

    events: list[Event] = []
    made = plan(machine, document, load_desired(document), report=events.append)
    assert [e.name for e in events if isinstance(e, Phase)] == ["resolve", "observe", "plan"]
    assert made.has_changes and not read_record(machine.layout).apps
