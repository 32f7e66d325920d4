"""The gates that govern a command are the workflow's to find, never the caller's:
operator commands and saved plans obey the desired state in force (workflow/gates.py)."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest

from reconciler.adapters.memory import MemoryGate
from reconciler.base.errors import ConfigError, Deferred
from reconciler.base.layout import Layout
from reconciler.engine.records.state import read_record
from reconciler.workflow import gates, operate
from reconciler.workflow.applying import ApplyOptions, apply_saved
from reconciler.workflow.events import Event
from reconciler.workflow.gates import Governing, governing
from reconciler.workflow.machine import Machine
from schemas.operator import OperatorAction
from tests.records import sole
from tests.unit.test_gate_execution import running_x

GATED = "version: 1\napp: null\ngates:\n  windows: ['00:00-23:59']\n"


def quiet(event: Event) -> None:
    pass


def test_the_desired_state_in_force_gives_the_gates(tmp_path: Path) -> None:
    machine = Machine.at(Layout(tmp_path), services="supervisor")
    assert governing(machine, None) == Governing(None, None)  # nothing in force: ungated
    machine.layout.desired_state.parent.mkdir(parents=True)
    machine.layout.desired_state.write_text(GATED)
    assert governing(machine, None).gate is not None
    assert governing(machine, None, force=True) == Governing(None, None)
    assert governing(machine, tmp_path / "absent.yaml") == Governing(None, None)


def test_an_unreadable_desired_state_leaves_the_gates_unknown_not_open(tmp_path: Path) -> None:
    machine = Machine.at(Layout(tmp_path), services="supervisor")
    machine.layout.desired_state.parent.mkdir(parents=True)
    machine.layout.desired_state.write_text("version: 1\ngates: [\n")
    with pytest.raises(ConfigError) as caught:
        governing(machine, None)
    assert caught.value.hint is not None and "--force" in caught.value.hint
    assert governing(machine, None, force=True).gate is None  # forced: nothing is read


def test_a_saved_plan_cannot_be_run_without_its_gates(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    assert "gate" not in inspect.signature(apply_saved).parameters
    asked: list[Path | None] = []

    def found(machine: Machine, file: Path | None, *, force: bool = False) -> Governing:
        asked.append(file)
        raise Deferred("closed")

    monkeypatch.setattr(gates, "governing", found)
    with pytest.raises(Deferred):
        apply_saved(Machine.at(Layout(tmp_path)), object(), "p.json",  # type: ignore[arg-type]
                    options=ApplyOptions(), report=quiet)
    assert asked == [None]


def test_an_operator_stop_obeys_the_gates_in_force(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    world = running_x(tmp_path)
    machine = Machine(world.layout, given_services=world.services)
    closed = Governing(MemoryGate(["moving: 30.0 km/h"]), None)
    monkeypatch.setattr(operate, "governing", lambda machine, file, force: closed)
    with pytest.raises(Deferred):
        operate.operate_installed(machine, OperatorAction.STOP, file=None, force=False,
                                  options=ApplyOptions(), report=quiet)
    app = sole(read_record(world.layout))
    assert app is not None and not app.held and world.scripts.calls == []
