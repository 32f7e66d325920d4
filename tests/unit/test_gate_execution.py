"""The executor at the gates, against the in-memory ports and the gate's twin: preparation
always runs, the cutover waits for every gate, a deferral changes nothing on the running
app and is journalled, and operator commands obey the gates unless forced."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import MemoryGate
from reconciler.base.errors import Deferred
from reconciler.core.planning.model import generation_id
from reconciler.core.planning.plan import make_plan
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.executor import execute
from reconciler.engine.observe.machine import observe
from reconciler.engine.records.journal import deferral, interrupted_steps
from reconciler.engine.records.state import read_record
from reconciler.workflow.operate import operate
from schemas.operator import OperatorAction
from schemas.record import AppRecord, RepositoryRecord, StateRecord
from tests.records import sole
from tests.unit.test_convergence import C1, C2, KEY, NOW, TREES, URL, World


def running_x(root: Path) -> World:
    app = AppRecord(name="x", repository=KEY, commit=C1, tree=TREES[("x", C1)], path="x",
                    generation=generation_id(TREES[("x", C1)], {}), status="running")
    record = StateRecord(lineage="L", serial=1, apps=[app],
                         repositories=[RepositoryRecord(key=KEY, url=URL, ref=None, commit=C1)])
    return World(root, record, [("x", C1, {})])


def context(world: World, gate: MemoryGate | None, wait: float = 0.0) -> Context:
    return Context(layout=world.layout, store=world.store, scripts=world.scripts,
                   services=world.services, record=read_record(world.layout),
                   clock=lambda: NOW, monotonic=world.monotonic, sleep=world.sleep,
                   gate=gate, gate_wait=wait,
                   folders=DiskFolders(layout=world.layout, store=world.store))


def apply(world: World, gate: MemoryGate | None, wait: float = 0.0) -> None:
    targets = world.targets(("x", C2, {}))
    plan = make_plan(targets, observe(world.layout, world.store, targets, world.services),
                     now=NOW, lpam_version="t")
    execute(plan, context(world, gate, wait), progress=lambda _: None)


def test_a_closed_gate_defers_the_cutover_after_everything_was_prepared(
    tmp_path: Path,
) -> None:
    world = running_x(tmp_path)
    gate = MemoryGate(["moving: 42.0 km/h"])
    with pytest.raises(Deferred, match=r"moving: 42\.0 km/h") as info:
        apply(world, gate)
    assert info.value.exit_code == 75
    assert world.scripts.calls == []  # x neither stopped nor uninstalled
    app = sole(read_record(world.layout))
    assert app is not None and (app.commit, app.status) == (C1, "running")
    assert world.store.head(KEY) == C2  # the preparation went ahead
    new = generation_id(TREES[("x", C2)], {})
    assert world.layout.generation_dir("x", new).is_dir()  # staged, ready for the cutover
    found = deferral(world.layout)
    assert found is not None and "moving" in found[1]
    assert interrupted_steps(world.layout) == []  # a deferral is not a crash
    assert (gate.holds, gate.releases) == (0, 0)


def test_the_next_apply_with_the_gates_open_cuts_over_and_releases_the_locks(
    tmp_path: Path,
) -> None:
    world = running_x(tmp_path)
    with pytest.raises(Deferred):
        apply(world, MemoryGate(["a lock is held"]))
    gate = MemoryGate([])
    apply(world, gate)
    assert world.scripts.calls == ["x:stop.sh", "x:uninstall.sh", "x:install.sh",
                                   "x:start.sh"]
    app = sole(read_record(world.layout))
    assert app is not None and app.commit == C2
    assert (gate.holds, gate.releases) == (1, 1)
    assert deferral(world.layout) is None


def test_waiting_rechecks_until_the_gates_open(tmp_path: Path) -> None:
    world = running_x(tmp_path)
    gate = MemoryGate(["moving"], ["stationary for 3 s of 60"], [])
    apply(world, gate, wait=5)
    assert world.scripts.calls[-1] == "x:start.sh" and gate.holds == 1
    world2 = running_x(tmp_path / "again")
    with pytest.raises(Deferred):  # not long enough: the third check never comes
        apply(world2, MemoryGate(["moving"], ["moving"], []), wait=1)


def test_a_gate_is_released_when_the_cutover_fails(tmp_path: Path) -> None:
    world = running_x(tmp_path)
    world.scripts.fail.add("x:install.sh")
    gate = MemoryGate([])
    with pytest.raises(Exception, match="install"):
        apply(world, gate)
    assert (gate.holds, gate.releases) == (1, 1)


def test_operator_commands_obey_the_gates_unless_forced(tmp_path: Path) -> None:
    world = running_x(tmp_path)
    with pytest.raises(Deferred):
        operate(context(world, MemoryGate(["moving: 30.0 km/h"])), OperatorAction.STOP,
                progress=lambda _: None)
    app = sole(read_record(world.layout))
    assert app is not None and not app.held and app.status == "running"
    assert world.scripts.calls == []
    gate = MemoryGate([])
    operate(context(world, gate), OperatorAction.STOP, progress=lambda _: None)
    assert world.scripts.calls == ["x:stop.sh"] and (gate.holds, gate.releases) == (1, 1)
    operate(context(world, None), OperatorAction.START,
            progress=lambda _: None)  # --force: no gate
    assert world.scripts.calls[-1] == "x:start.sh"
