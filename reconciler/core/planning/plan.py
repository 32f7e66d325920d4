"""Assemble, seal and check a plan: the only input `apply` executes.

The fingerprint (schemas/plan.py, where the loader checks it too) covers what drives
behaviour (the record it was made against and the steps), never display text, so a
reworded reason does not invalidate a plan while an edited step does.
"""

from __future__ import annotations

from datetime import datetime

from reconciler.base.errors import PlanError, StalePlanError
from reconciler.core.planning.decision import Held
from reconciler.core.planning.diff import apps_planned, diff
from reconciler.core.planning.graph import steps_for
from reconciler.core.planning.holds import release_command
from reconciler.core.planning.model import UNKNOWN, Observed, Targets
from reconciler.core.planning.settling import HELD
from schemas.generation import AppGeneration, StrayGeneration
from schemas.plan import Action, BuildStep, Change, CheckoutStep, Plan, Step, fingerprint
from schemas.record import StateRecord

__all__ = ["check_plan", "fingerprint", "make_plan", "seal", "unknown_values"]


def make_plan(
    targets: Targets, observed: Observed, *, now: datetime, lpam_version: str,
    offline: bool = False, hold: str | None = None,
) -> Plan:
    """The plan toward the desired state. `hold`: a rollback holds the machine (the
    reason); the plan proposes nothing."""
    if hold is not None:
        changes = [Change(address="hold", action=Action.NOOP, reason=hold, warnings=[hold])]
        steps: list[Step] = []
        stopped = [a.name for a in observed.record.apps if a.held]
    else:
        apps = apps_planned(targets, observed)  # each app decided once: changes and steps
        changes = diff(targets, observed, apps)
        steps = steps_for(changes, targets, observed, apps)
        stopped = [d.app for d in apps.decisions
                   if isinstance(d.reason, Held) and d.reason.operator]
    summary = None
    if all(c.action is Action.NOOP for c in changes) and (hold is not None or stopped):
        summary = held_summary(observed.record, rollback=hold is not None, stopped=stopped)
    return seal(observed.record, changes, steps, now=now, lpam_version=lpam_version,
                offline=offline, summary=summary)


def held_summary(record: StateRecord, *, rollback: bool, stopped: list[str]) -> str | None:
    """A plan with nothing to do because holds keep the machine from the desired state:
    never "the machine matches the desired state" then, but each hold and how it ends."""
    holds = []
    if rollback and record.hold is not None:
        holds.append(f"`lpam rollback` holds generation {record.hold.name} (a change of the "
                     f"desired state or `{release_command(record)}` ends it)")
    if stopped:
        one = len(stopped) == 1
        start = f"`lpam start {stopped[0]}` starts it" if one else \
            "`lpam start` starts them"
        holds.append(f"{', '.join(stopped)} stopped by `lpam stop` ({start})")
    return f"{HELD}{'; '.join(holds)}." if holds else None


def seal(record: StateRecord, changes: list[Change], steps: list[Step], *, now: datetime,
         lpam_version: str, summary: str | None = None, offline: bool = False) -> Plan:
    """The one place a plan is made: against `record` (its lineage and serial, so a plan
    made against another state is refused), sealed by its fingerprint. `summary`: what
    the plan does, when it is not counted from its changes (an operator's command, a
    rollback)."""
    if summary is None:
        counts = {a: sum(1 for c in changes if c.action is a) for a in Action}
        summary = (
            f"Plan: {counts[Action.CREATE]} to add, {counts[Action.UPDATE]} to change, "
            f"{counts[Action.REPLACE]} to replace, {counts[Action.DELETE]} to destroy."
            if any(c.action is not Action.NOOP for c in changes)
            else "No changes. The machine matches the desired state."
        )
    plan = Plan(lpam_version=lpam_version, created_at=now.isoformat(timespec="seconds"),
                lineage=record.lineage, serial=record.serial, changes=changes, steps=steps,
                summary=summary, offline=offline)
    return plan.model_copy(update={"fingerprint": fingerprint(plan)})


_MUST_KNOW = ("repository", "commit", "path", "tree", "generation")


def _must_know(step: Step) -> dict[str, object]:
    """The values of `step` a plan must know to run (named as version 1 named them)."""
    values: dict[str, object] = {}
    if isinstance(step, (CheckoutStep, BuildStep)):
        values = step.model_dump(include={"commit", "build", "ros"})
    target = getattr(step, "target", None) or getattr(step, "app", None)
    if isinstance(target, StrayGeneration):
        values["generation"] = target.generation
    elif isinstance(target, AppGeneration):
        values.update({name: getattr(target, name) for name in _MUST_KNOW})
        if target.ros or target.ros_build is not None:
            values.update(build=target.ros_build, ros=target.ros)
    return values


def unknown_values(plan: Plan) -> list[str]:
    """`step.arg` for every value a plan must know to run but does not."""
    return [
        f"{step.id}.{name}"
        for step in plan.steps
        for name, value in _must_know(step).items()
        if value is None or UNKNOWN in str(value)
    ]


def check_plan(plan: Plan, *, lineage: str | None, serial: int, source: str) -> None:
    """Refuse a plan that was edited, or made against another state than the current one."""
    if plan.fingerprint != fingerprint(plan):
        raise PlanError(
            f"{source}: the plan's fingerprint does not match its steps (edited or corrupt)",
            hint="make a new plan with `lpam plan --out FILE`",
        )
    unknown = unknown_values(plan)
    if plan.offline or unknown:
        raise PlanError(
            f"{source}: the plan was made offline or holds values still unknown "
            f"({', '.join(unknown) or 'offline'}); it cannot be applied",
            hint="make an exact plan with `lpam plan --out FILE` (with network)",
        )
    if plan.lineage is not None and plan.lineage != lineage:
        raise StalePlanError(
            f"{source} was made for another machine state (lineage {plan.lineage}, "
            f"this machine has {lineage})",
            hint="make a new plan with `lpam plan --out FILE` on this machine",
        )
    if plan.serial != serial:
        raise StalePlanError(
            f"{source} is stale: the state changed since it was made "
            f"(serial {plan.serial}, now {serial})",
            hint="review a fresh plan with `lpam plan --out FILE`, then apply that",
        )
