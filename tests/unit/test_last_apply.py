"""The last apply is a closed state machine (issue 30, "What to build" 1): in progress
(its process alive), deferred (which gates, what tries again), interrupted, cut off (in
progress, its process gone: derived, never written), succeeded, failed, rolled back.
Status derives each word from the record and whether the pid lives, so no face says two
of them at once, and an apply with nothing to do ends one that no longer applies.

Built from values (the report is pure) and, for what writes the record, against the
in-memory ports and the gate's twin."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

import pytest

from reconciler.adapters.memory import MemoryGate
from reconciler.base.errors import Deferred
from reconciler.engine.execution.recovery import settled
from reconciler.engine.records.state import read_record
from reconciler.report import table
from reconciler.report.build import build, last_state
from reconciler.report.gather import Seen
from reconciler.report.status import json_of
from schemas.record import (
    AppRecord,
    Cutover,
    DesiredRef,
    LastApply,
    LastResult,
    RepositoryRecord,
    Rollback,
    StateRecord,
)
from tests.unit.test_convergence import NOW
from tests.unit.test_gate_execution import apply, context, running_x

WHEN = "2026-11-27T10:00:00+00:00"
COMMAND = "lpam --root /car apply -f /car/etc/lpam/desired-state.yaml"
ALPHA = AppRecord(name="alpha", repository="apps", commit="c" * 40, tree="t" * 40,
                  path="alpha/", generation="alp-g1", status="running")


def record(last: LastApply | None, *, cutover: Cutover | None = None) -> StateRecord:
    return StateRecord(apps=[ALPHA], last_apply=last, cutover=cutover,
                       repositories=[RepositoryRecord(key="apps", url="git://x/apps.git",
                                                      ref="main", commit="d" * 40,
                                                      applied="c" * 40)])


def said(rec: StateRecord, *, alive: bool = False) -> tuple[str, dict]:  # type: ignore[type-arg]
    """The table and the JSON of `lpam status` for this record."""
    report = build(Seen(record=rec, alive=alive))
    return table.render(report), json_of(report)


IN_PROGRESS = LastApply(time=WHEN, result="in progress", pid=4242, command=COMMAND)
DEFERRED = LastApply(time=WHEN, result="deferred", gates=["vehicle"],
                     reason="vehicle: closed — moving: 57.7 km/h from currentCan.csv")
CUTOVER = Cutover(previous=[ALPHA], began=WHEN)


@pytest.mark.parametrize(("result", "alive", "state", "words"), [
    ("in progress", True, "in progress", "Last apply: in progress since"),
    ("in progress", False, "cut off", "Last apply: cut off (began"),
    ("deferred", False, "deferred", "Last apply: deferred at"),
    ("interrupted", False, "interrupted", "Last apply: interrupted at"),
    ("applied", False, "succeeded", "Last apply: applied at"),
    ("failed", False, "failed", "Last apply: failed at"),
    ("rolled back", False, "rolled back", "Last apply: rolled back at"),
])
def test_each_state_has_one_word_in_the_table_and_the_json(
    result: LastResult, alive: bool, state: str, words: str,
) -> None:
    last = LastApply(time=WHEN, result=result, reason="why",
                     pid=4242 if result == "in progress" else None, command=COMMAND)
    text, body = said(record(last), alive=alive)
    assert words in text, text
    assert body["last_apply"]["state"] == state
    others = {"in progress", "cut off", "deferred"} - {state}
    line = next(x for x in text.splitlines() if x.startswith("Last apply:"))
    assert not any(word in line for word in others), line


def test_a_live_apply_mid_cutover_is_never_said_to_be_cut_off() -> None:
    """Item 2: during a running apply the cutover is the live apply's own."""
    text, body = said(record(IN_PROGRESS, cutover=CUTOVER), alive=True)
    assert "Last apply: in progress since" in text
    assert "Cutover under way since" in text and "returns to alpha" in text
    assert "cut off" not in text, text
    assert body["last_apply"]["state"] == "in progress"


def test_a_live_rollback_is_said_to_be_under_way_not_cut_off() -> None:
    rollback = Rollback(failed=[ALPHA], reason="step start:beta failed", time=WHEN)
    text, _ = said(record(IN_PROGRESS, cutover=CUTOVER.model_copy(
        update={"rollback": rollback})), alive=True)
    assert "Rolling back to alpha" in text and "cut off" not in text, text


def test_a_dead_apply_mid_cutover_is_cut_off_in_both_lines() -> None:
    text, body = said(record(IN_PROGRESS, cutover=CUTOVER), alive=False)
    assert "Last apply: cut off (began" in text and f"`{COMMAND}`" in text
    assert "Apply cut off mid-cutover" in text and "in progress" not in text
    assert body["last_apply"]["state"] == "cut off"
    cutover = next(line for line in text.splitlines() if "mid-cutover" in line)
    assert f"`{COMMAND}` goes on from here" in cutover, cutover  # the file it worked toward


def test_a_deferred_apply_is_shown_as_deferred_never_as_killed() -> None:
    """Item 1: which gate, what tries again; no hint to resume a file that may be stale."""
    text, body = said(record(DEFERRED))
    line = next(x for x in text.splitlines() if x.startswith("Last apply:"))
    assert line.startswith(f"Last apply: deferred at {WHEN}: the update gates were closed")
    assert "moving: 57.7 km/h" in line and "nothing on the running app changed" in line
    assert "the next `lpam apply` tries again" in line
    for wrong in ("cut off", "killed", "power failed", "-f ", "goes on from"):
        assert wrong not in text, text
    assert body["last_apply"]["state"] == "deferred"
    assert body["deferred"] == {"time": WHEN, "reason": DEFERRED.reason,
                                "gates": ["vehicle"], "retry": None}


def test_a_deferral_by_the_agent_says_when_its_next_pass_tries_again() -> None:
    last = DEFERRED.model_copy(update={"retry": "2026-11-27T10:05:00+00:00"})
    text, body = said(record(last))
    assert "the agent's next pass tries again at about 2026-11-27T10:05:00+00:00" in text
    assert body["deferred"]["retry"] == "2026-11-27T10:05:00+00:00"


def test_no_state_is_said_with_another() -> None:
    """Over every written result, alive or not, with or without a cutover: the table
    never says "in progress" beside "cut off", and the JSON's state is the table's."""
    results: tuple[LastResult, ...] = ("applied", "failed", "rolled back", "in progress",
                                       "interrupted", "deferred")
    for result in results:
        for alive in (True, False):
            for cutover in (None, CUTOVER):
                last = LastApply(time=WHEN, result=result, pid=7, command=COMMAND)
                text, body = said(record(last, cutover=cutover), alive=alive)
                assert not ("in progress" in text and "cut off" in text), text
                assert body["last_apply"]["state"] == last_state(last, alive=alive)


def test_the_executor_records_a_deferral_as_deferred_with_its_gates(tmp_path: Path) -> None:
    """A closed gate ends the apply `deferred`, not `in progress` with a pid soon gone."""
    world = running_x(tmp_path)
    with pytest.raises(Deferred):
        apply(world, MemoryGate(["moving: 42.0 km/h"]))
    last = read_record(world.layout).last_apply
    assert last is not None
    assert (last.result, last.gates, last.pid, last.command, last.retry) == \
        ("deferred", ["vehicle"], None, None, None)
    assert last.reason == "vehicle: closed — moving: 42.0 km/h"
    assert "deferred at" in table.render(build(Seen(record=read_record(world.layout))))


def test_the_agents_deferral_names_its_next_pass(tmp_path: Path) -> None:
    from reconciler.core.planning.plan import make_plan
    from reconciler.engine.execution.executor import execute
    from reconciler.engine.observe.machine import observe
    from tests.unit.test_convergence import C2

    world = running_x(tmp_path)
    targets = world.targets(("x", C2, {}))
    plan = make_plan(targets, observe(world.layout, world.store, targets, world.services),
                     now=NOW, lpam_version="t")
    ctx = context(world, MemoryGate(["moving"]))
    ctx.retry_after = 300.0
    with pytest.raises(Deferred):
        execute(plan, ctx, progress=lambda _: None)
    last = read_record(world.layout).last_apply
    assert last is not None and last.retry == \
        (NOW + timedelta(seconds=300)).isoformat(timespec="seconds")


def test_a_deferral_leaves_the_desired_state_in_force_as_it_was(tmp_path: Path) -> None:
    """Nothing was applied: an operator's stop, held against the desired state in force,
    must not end because an apply of another file was deferred (holds.released)."""
    from reconciler.core.planning.plan import make_plan
    from reconciler.engine.execution.executor import execute
    from reconciler.engine.observe.machine import observe
    from reconciler.engine.records.state import write_record
    from tests.unit.test_convergence import C2

    world = running_x(tmp_path)
    in_force = DesiredRef(fingerprint="a" * 64, source="/car/a.yaml")
    write_record(world.layout, read_record(world.layout).model_copy(
        update={"desired": in_force}))
    targets = world.targets(("x", C2, {}))
    plan = make_plan(targets, observe(world.layout, world.store, targets, world.services),
                     now=NOW, lpam_version="t")
    ctx = context(world, MemoryGate(["moving"]))
    ctx.desired = DesiredRef(fingerprint="b" * 64, source="/car/b.yaml")
    with pytest.raises(Deferred):
        execute(plan, ctx, progress=lambda _: None)
    after = read_record(world.layout)
    assert after.desired == in_force
    assert after.last_apply is not None and after.last_apply.result == "deferred"


def test_nothing_to_do_under_a_rollbacks_hold_says_nothing_of_the_checkouts() -> None:
    """The car is what the rollback returned to, not what the checkouts hold."""
    from schemas.record import Hold

    held = record(IN_PROGRESS).model_copy(update={"hold": Hold(desired="f" * 64)})
    after = settled(held, now=WHEN, desired=None)
    assert after is not None and [r.applied for r in after.repositories] == ["c" * 40]


@pytest.mark.parametrize("stale", ["in progress", "deferred", "interrupted"])
def test_an_apply_with_nothing_to_do_ends_a_stale_last_apply(stale: LastResult) -> None:
    desired = DesiredRef(fingerprint="f" * 64, source="/car/etc/lpam/desired-state.yaml")
    before = record(LastApply(time=WHEN, result=stale, pid=1, command=COMMAND),
                    cutover=CUTOVER)
    after = settled(before, now="2026-11-27T11:00:00+00:00", desired=desired)
    assert after is not None and after.last_apply is not None
    assert (after.last_apply.result, after.cutover, after.desired) == ("applied", None, desired)
    assert [r.applied for r in after.repositories] == ["d" * 40]
    text, body = said(after)
    assert body["last_apply"]["state"] == "succeeded" and body["deferred"] is None
    assert "nothing was left to do: the machine matched the desired state" in text
    assert "cut off" not in text


def test_an_apply_that_ends_a_cut_off_one_under_a_stop_never_says_the_car_matched() -> None:
    """The field trial on libpanda-default-apps: an apply killed at its start step, `lpam
    stop`, then `lpam apply`: the car differs from the desired state on purpose (the stop
    holds the app), so the apply that ends the cut-off one says so — not "the machine
    matched the desired state", which `lpam plan` would contradict."""
    stopped = ALPHA.model_copy(update={"held": True, "status": "installed"})
    before = record(IN_PROGRESS, cutover=CUTOVER).model_copy(update={"apps": [stopped]})
    after = settled(before, now="2026-11-27T11:00:00+00:00", desired=None)
    assert after is not None and after.last_apply is not None
    text, _ = said(after)
    assert "nothing was left to do: the holds in force keep the rest as it is" in text
    assert "matched" not in text


def test_an_apply_with_nothing_to_do_writes_nothing_after_a_settled_one() -> None:
    """A saved plan stays valid: nothing owed, nothing written (no new serial)."""
    settled_results: tuple[LastResult, ...] = ("applied", "failed", "rolled back")
    for result in settled_results:
        last = LastApply(time=WHEN, result=result)
        assert settled(record(last), now=WHEN, desired=None) is None
    assert settled(record(None), now=WHEN, desired=None) is None
    rollback = Rollback(reason="x", time=WHEN)  # a rollback owed is finished by its plan
    owed = record(LastApply(time=WHEN, result="failed"),
                  cutover=CUTOVER.model_copy(update={"rollback": rollback}))
    assert settled(owed, now=WHEN, desired=None) is None


def test_an_apply_of_another_desired_state_with_nothing_to_do_ends_a_rollbacks_hold() -> None:
    """Found by the consistency property: apply {z}; apply {}; rollback (back to z); apply
    {z} — the desired state changed, so the hold no longer holds and the car matches; the
    hold stayed in the record and status kept naming it above "No changes"."""
    from schemas.record import Hold

    last = LastApply(time=WHEN, result="applied")
    held = record(last).model_copy(update={"hold": Hold(desired="f" * 64)})
    same = DesiredRef(fingerprint="f" * 64, source="/car/etc/lpam/desired-state.yaml")
    assert settled(held, now=WHEN, desired=same) is None  # the hold still holds
    other = DesiredRef(fingerprint="e" * 64, source="/car/etc/lpam/desired-state.yaml")
    after = settled(held, now=WHEN, desired=other)
    assert after is not None and after.hold is None and after.desired == other
    assert "Held:" not in said(after)[0]


def test_an_apply_of_another_desired_state_ends_a_hold_even_when_it_installs_the_same_set(
) -> None:
    """Found by the consistency property: apply {z}; apply {}; rollback (back to z); z's
    unit stopped outside; apply {z} starts it — of a desired state other than the one held
    against, so the hold ends, though the set is the one the rollback returned to."""
    from reconciler.engine.execution.recovery import hold_after
    from schemas.record import HistoryEntry, Hold

    z = AppRecord(name="z", repository="apps", commit="c" * 40, tree="t" * 40, path="z/",
                  generation="z-g1", status="running")
    back = HistoryEntry(generation="z-g1", app="z", repository="apps", commit="c" * 40,
                        path="z/", tree="t" * 40, time=WHEN, result="applied")
    held = StateRecord(apps=[z], hold=Hold(desired="f" * 64, targets=[back]))
    same = DesiredRef(fingerprint="f" * 64, source="/car/etc/lpam/desired-state.yaml")
    other = DesiredRef(fingerprint="e" * 64, source="/car/etc/lpam/desired-state.yaml")
    assert hold_after(held, "applied", same) == held.hold  # it finished the rollback
    assert hold_after(held, "applied", other) is None
