"""The planner's modes besides the desired state's (plan.make_plan): the plans of an
operator's command, of `lpam rollback`, of a rollback held, and of finishing a rollback a
fault cut off. Each is planned by the same rules (core/planning/ensemble.py: one decision
per app) and sealed by the one `seal`, so the executor runs them all alike.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from datetime import datetime

from reconciler.base.unit import UnitState
from reconciler.core.planning.ensemble import operator_steps, plan_set
from reconciler.core.planning.graph import order
from reconciler.core.planning.lifecycle import refreshed, target_of
from reconciler.core.planning.model import GenerationKey, Observed, RepoTarget, Targets
from reconciler.core.planning.plan import make_plan, seal
from schemas.operator import OperatorAction
from schemas.plan import Action, Change, Plan, Step
from schemas.record import AppRecord, HistoryEntry, StateRecord


def names(apps: Sequence[AppRecord]) -> str:
    return ", ".join(a.name for a in apps)


def steps_back(record: StateRecord, previous: Sequence[AppRecord],
               generations: frozenset[GenerationKey]) -> list[Step]:
    """The steps back to `previous` (a failed cutover's rollback, `lpam rollback`). The
    car must not be left with no app: each previous app is started again unless an
    operator had stopped it — then, or now: an operator's stop holds through a rollback
    (after a crash its status may say `installing` though it ran); one whose stop.sh just
    failed is brought back up, not stopped again."""
    for app in record.apps:
        before = next((p for p in previous if p.name == app.name), None)
        if before is not None and app.status == "stopping" and \
                app.generation == before.generation:
            record = record.with_app(app.name, app.model_copy(update={"status": "starting"}))
    targets = [target_of(p) for p in previous]
    held = {p.name for p in previous if p.held} | {a.name for a in record.apps if a.held}
    return order(plan_set(record, targets, generations, verify=False, stopped=held).steps)


def operator_plan(record: StateRecord, action: OperatorAction,
                  generations: frozenset[GenerationKey], *, chosen: Collection[str],
                  now: datetime, lpam_version: str) -> Plan:
    """`lpam start|stop|restart` of the installed apps `chosen`."""
    steps = operator_steps(record, action, generations, names=chosen)
    return seal(record, [], steps, now=now, lpam_version=lpam_version,
                summary=f"{action} {', '.join(chosen)}")


def rollback_plan(record: StateRecord, entries: Sequence[HistoryEntry],
                  generations: frozenset[GenerationKey], *, now: datetime,
                  lpam_version: str) -> Plan:
    """`lpam rollback` to the set of apps `entries` (the history's previous good set)."""
    steps = steps_back(record, [e.installed() for e in entries], generations)
    named = ", ".join(f"{e.app}@{e.generation}" for e in entries)
    return seal(record, [], steps, now=now, lpam_version=lpam_version,
                summary=f"roll back to {named}")


def hold_targets(record: StateRecord) -> Targets | None:
    """What a rollback that holds returns to, as targets (None: nothing named): planned
    against the machine, they are the steps that finish a rollback a fault cut off."""
    entries = record.hold.targets if record.hold is not None else []
    if not entries:
        return None
    repos = tuple(RepoTarget(r.key, r.url, r.ref, r.commit) for r in record.repositories)
    return Targets(repos, tuple(target_of(e.installed()) for e in entries))


def held_plan(record: StateRecord, reason: str, finishing: tuple[Targets, Observed] | None,
              *, now: datetime, lpam_version: str) -> tuple[Plan, bool]:
    """While a rollback holds: the steps that finish it if it was cut off (`finishing`:
    its targets as observed), else nothing. Whether it finishes a cut-off rollback."""
    if finishing is not None:
        targets, observed = finishing
        made = make_plan(targets, observed, now=now, lpam_version=lpam_version)
        if made.steps:
            return made, True
    return make_plan(Targets(()), Observed(record=record, repositories={}), now=now,
                     lpam_version=lpam_version, hold=reason), False


def finishing_plan(record: StateRecord, lives: Mapping[str, UnitState],
                   generations: frozenset[GenerationKey], *, now: datetime,
                   lpam_version: str) -> Plan:
    """A rollback that a fault cut off is finished before anything else: its steps back
    to the good apps it was returning to, by the rules of any plan, whatever the desired
    state says now (the next run goes on from there)."""
    assert record.cutover is not None and record.cutover.rollback is not None
    previous, rollback = record.cutover.previous, record.cutover.rollback
    failed = names(rollback.failed) if rollback.failed else "the new app"
    back = finished_to(record)
    reason = (f"the rollback {back} after {failed} failed ({rollback.reason}) was cut off "
              "by a fault: finished, and the failure recorded")
    steps = steps_back(refreshed(record, lives), previous, generations)
    return seal(record, [Change(address="rollback", action=Action.UPDATE, reason=reason)],
                steps, now=now, lpam_version=lpam_version,
                summary=f"Plan: finish the rollback {back}.")


def finished_to(record: StateRecord) -> str:
    """Where a cut-off rollback returns: `to alpha, beta`, or `removing the new app`."""
    previous = record.cutover.previous if record.cutover is not None else []
    return f"to {names(previous)}" if previous else "removing the new app"
