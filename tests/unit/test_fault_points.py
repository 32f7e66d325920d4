"""Faults at every instant of a switch to a failing app and of its rollback, of an
operator's stop, and with the journal or the state record unwritable — through the real
planner, executor, steps and state record (on a temporary root), with the in-memory twins
of the ports that model the vehicle (tests/unit/test_convergence.py).

The car starts with `x` running and good. The desired app is `z`, a scriptless app whose
health command always fails. lpam dies (`Crash`: SIGKILL, a power cut) at the k-th
instant — before, during or after any script or unit operation, or right after any write
of the state record — and the next apply must tell the truth: it never reports success,
it finishes the health check or the rollback that was cut off, and the car ends with `x`
running, the failure in the history and the last apply's result. Never two apps at once.
"""

from __future__ import annotations

import contextlib
import errno
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import Crash
from reconciler.base.errors import HealthError, LpamError, StateWriteError
from reconciler.base.layout import Layout
from reconciler.core.planning.model import AppTarget, HealthTarget
from reconciler.core.planning.plan import make_plan
from reconciler.engine.execution import context as context_module
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.executor import execute
from reconciler.engine.observe.machine import observe
from reconciler.engine.records.state import read_record, write_record
from reconciler.workflow.operate import operate
from schemas.operator import OperatorAction
from schemas.plan import Plan
from schemas.record import StateRecord
from tests.records import sole
from tests.unit.test_convergence import C1, COMMAND, KEY, NOW, TREES, World

FAILING = ("./healthy.sh",)


class Car(World):
    """A World whose applies can die at any instant, and whose `z` fails its health."""

    def __init__(self, root: Path) -> None:
        super().__init__(root, StateRecord(), [])
        self.saves = 0
        self.save_hook: Callable[[int], None] = lambda n: None
        self.notes: list[str] = []
        failing = self.scripts.check

        def check(app: str, app_dir: Path, argv: list[str], params: dict[str, str], *,
                  timeout: float) -> tuple[bool, str]:
            if app == "z":  # always: every attempt fails, not only the first
                if self.scripts.crash("z:check") is not None:  # lpam dies in its check
                    raise Crash("z:check")
                self.scripts.calls.append("z:check")
                return False, "exit code 1"
            return failing(app, app_dir, argv, params, timeout=timeout)

        self.scripts.check = check  # type: ignore[method-assign]

    def target(self, name: str) -> AppTarget:
        health = HealthTarget(settle_seconds=1, command=FAILING if name == "z" else None)
        return AppTarget(name=name, repository=KEY, commit=C1, path=name,
                         tree=TREES[(name, C1)], command=COMMAND if name == "z" else None,
                         service="lpam-app-z" if name == "z" else None, health=health)

    def context(self) -> Context:
        car = self

        class Saving(Context):
            def save(self, record: StateRecord) -> None:
                car.saves += 1
                car.save_hook(car.saves)
                super().save(record)

        return Saving(layout=self.layout, store=self.store, scripts=self.scripts,
                      services=self.services, record=read_record(self.layout),
                      clock=lambda: NOW, monotonic=self.monotonic, sleep=self.sleep,
                      folders=DiskFolders(layout=self.layout, store=self.store))

    def run(self, name: str) -> LpamError | None:
        """One `lpam apply` of `name`, as the workflow makes it (a rollback that was cut
        off is finished first); the error it ended with, None on success."""
        from reconciler.core.planning.model import RepoTarget, Targets

        targets = Targets((RepoTarget(KEY, "git://h/apps", None, C1),), (self.target(name),))
        record = read_record(self.layout)
        if record.cutover is not None and record.cutover.rollback is not None:
            plan = self.finishing(record)
        else:
            plan = make_plan(targets, observe(self.layout, self.store, targets, self.services),
                             now=NOW, lpam_version="t")
        try:
            execute(plan, self.context(), progress=self.notes.append)
        except LpamError as exc:
            return exc
        return None

    def finishing(self, record: StateRecord) -> Plan:
        from reconciler.workflow.machine import Machine
        from reconciler.workflow.planning import _finishing_plan

        machine = Machine(self.layout, given_services=self.services, clock=lambda: NOW)
        return _finishing_plan(machine, record, lambda event: None)

    def active(self) -> set[str]:
        on = set(self.scripts.active)
        if self.services.state("lpam-app-z").running:
            on.add("z")
        return on


def good_x(root: Path) -> Car:
    car = Car(root)
    assert car.run("x") is None
    record = read_record(car.layout)
    assert (sole(record).name, sole(record).good) == ("x", True)
    return car


def instants(kind: str) -> int:
    """How many instants a calm switch to z has, of each kind (calls, saves)."""
    with tempfile.TemporaryDirectory() as tmp:
        car = good_x(Path(tmp))
        car.saves, car.scripts.calls = 0, []
        assert isinstance(car.run("z"), HealthError)
        return len(car.scripts.calls) if kind == "call" else car.saves


CALLS = instants("call")
SAVES = instants("save")


def assert_truth_after_recovery(car: Car) -> None:
    """The next apply finishes what was cut off and says the switch failed; the car runs
    x, good; the failure is in history and the last apply's result."""
    again = car.run("z")
    assert isinstance(again, HealthError), again  # never reported as success
    record = read_record(car.layout)
    assert sole(record).name == "x" and sole(record).running
    assert sole(record).good and record.cutover is None
    assert record.last_apply is not None and record.last_apply.result == "rolled back"
    assert [h.app for h in record.history if h.result == "rolled back"][-1:] == ["z"]
    assert [h.app for h in record.history if h.result == "applied"] == ["x"]  # z never was
    assert car.active() == {"x"}
    assert not car.scripts.violations, car.scripts.violations


@pytest.mark.parametrize("when", ["before", "during", "after"])
@pytest.mark.parametrize("k", range(CALLS))
def test_a_crash_at_any_call_of_a_failing_switch_is_finished_truthfully(
    tmp_path: Path, k: int, when: str
) -> None:
    car = good_x(tmp_path)
    seen: list[str] = []

    def crash_at(call: str) -> str | None:
        seen.append(call)
        return when if len(seen) == k + 1 else None

    car.scripts.crash = crash_at
    with pytest.raises(Crash):
        car.run("z")
    car.scripts.crash = lambda call: None
    assert car.active() <= {"x", "z"} and not car.scripts.violations
    assert_truth_after_recovery(car)


@pytest.mark.parametrize("k", range(SAVES))
def test_a_crash_after_any_write_of_the_record_is_finished_truthfully(
    tmp_path: Path, k: int
) -> None:
    car = good_x(tmp_path)
    car.saves = 0

    def die(n: int) -> None:
        if n == k + 1:  # the k-th write landed; lpam dies before the next one
            raise Crash(f"after write {k}")

    car.save_hook = die
    with pytest.raises(Crash):
        car.run("z")
    car.save_hook = lambda n: None
    assert_truth_after_recovery(car)


def test_only_a_good_generation_is_returned_to(tmp_path: Path) -> None:
    """z is cut off mid-check; then the wish changes to y, which fails to start: the car
    goes back to x, the last good one, never to z, which never proved itself."""
    car = good_x(tmp_path)
    car.scripts.crash = lambda call: "before" if call == "z:check" else None
    with pytest.raises(Crash):
        car.run("z")
    car.scripts.crash = lambda call: None
    record = read_record(car.layout)
    assert (sole(record).name, sole(record).good) == ("z", False)
    car.scripts.fail = {"y:start.sh"}
    failed = car.run("y")
    assert isinstance(failed, LpamError) and "Rolled back to x" in failed.message
    record = read_record(car.layout)
    assert sole(record).name == "x" and sole(record).running
    assert car.active() == {"x"} and not car.scripts.violations


@pytest.mark.parametrize("k", range(1, 6))
def test_an_operators_stop_cut_off_anywhere_is_carried_out(tmp_path: Path, k: int) -> None:
    car = good_x(tmp_path)
    car.saves = 0

    def die(n: int) -> None:
        if n == k:
            raise Crash(f"at write {k}")

    car.save_hook = die
    with contextlib.suppress(Crash):
        operate(car.context(), OperatorAction.STOP, progress=car.notes.append)
    car.save_hook = lambda n: None
    record = read_record(car.layout)
    if record.apps and sole(record).held:  # the stop was asked for: it holds
        assert car.run("x") is None
        record = read_record(car.layout)
        assert sole(record).held and sole(record).status == "installed"
        assert car.active() == set()
        targets_plan = car.pending(("x", C1, {}))
        assert targets_plan == [], targets_plan
    else:  # lpam died before the stop was asked for: nothing changed
        assert car.active() == {"x"}


@pytest.mark.parametrize("k", range(12))
def test_a_journal_made_unwritable_mid_apply_does_not_stop_it(tmp_path: Path, k: int) -> None:
    """The journal is advisory: a path made a directory (or a full disk that only it
    meets) is reported once and the switch goes on to its end."""
    car = good_x(tmp_path)
    seen: list[str] = []

    def unwritable(call: str) -> None:
        seen.append(call)
        if len(seen) == k + 1:
            car.layout.journal.unlink()
            car.layout.journal.mkdir()

    car.scripts.crash = unwritable
    assert car.run("y") is None
    record = read_record(car.layout)
    assert (sole(record).name, sole(record).running) == ("y", True)
    assert car.active() == {"y"} and not car.scripts.violations
    if len(seen) > k:
        notes = [n for n in car.notes if "journal could not be written" in n]
        assert len(notes) == 1, car.notes


@pytest.mark.parametrize("k", range(1, 14))
def test_an_unwritable_record_stops_where_it_stands_and_says_so(
    tmp_path: Path, k: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """From the k-th write on, the disk is full. Nothing is done that the record on disk
    does not show (it never claims less than may run), the error says what it shows, and
    once the disk has room the next apply converges."""
    car = good_x(tmp_path)
    writes = [0]

    def full(layout: Layout, record: StateRecord) -> StateRecord:
        writes[0] += 1
        if writes[0] >= k:
            raise OSError(errno.ENOSPC, "No space left on device")
        return write_record(layout, record)

    monkeypatch.setattr(context_module, "write_record", full)
    outcome = car.run("y")
    monkeypatch.setattr(context_module, "write_record", write_record)
    record = read_record(car.layout)
    if outcome is not None:
        assert isinstance(outcome, StateWriteError), outcome
        assert "The record shows" in outcome.message and outcome.hint
        assert "Traceback" not in outcome.message
    recorded = {sole(record).name} if record.apps else set()
    assert car.active() <= recorded, (car.active(), sole(record))  # never less than may run
    assert not car.scripts.violations
    assert car.run("y") is None
    record = read_record(car.layout)
    assert (sole(record).name, sole(record).running) == ("y", True)
    assert car.active() == {"y"} and not car.scripts.violations


def test_with_no_cutover_recorded_an_unproven_app_is_never_returned_to(tmp_path: Path) -> None:
    """The good app to go back to, when no cut-off apply named one: the installed app if
    it proved good, else the newest good generation of it in the history still on disk."""
    from reconciler.engine.execution.recovery import returns_to
    from reconciler.engine.records import generations

    car = good_x(tmp_path)
    x = sole(read_record(car.layout))
    assert x is not None
    assert returns_to(read_record(car.layout), generations.present(car.layout)) == [x]
    unproven = x.model_copy(update={"generation": "x-new", "good": False})
    record = read_record(car.layout).model_copy(update={"apps": [unproven], "cutover": None})
    [back] = returns_to(record, generations.present(car.layout))
    assert (back.name, back.generation, back.good) == ("x", x.generation, True)
    gone = record.model_copy(update={"history": []})  # nothing good known: what is there
    assert returns_to(gone, generations.present(car.layout)) == [unproven]
