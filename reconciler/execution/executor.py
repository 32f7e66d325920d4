"""Run a plan's steps in order, journalling each one before and after its work.

A failed step stops the apply at once with a message that says where the vehicle stands:
a failure while preparing left the running app untouched; a failure in the cutover says
which app, if any, is installed now. The next apply re-plans from the state record, so it
resumes where this one stopped.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable

from reconciler.errors import LpamError, StepError
from reconciler.execution.journal import Journal
from reconciler.execution.steps import RUNNERS, Context
from schemas.plan import Phase, Plan


def execute(plan: Plan, ctx: Context, *, progress: Callable[[str], None]) -> None:
    journal = Journal(ctx.layout, apply_id=str(uuid.uuid4()), plan=plan.fingerprint)
    journal.open(ctx.clock())
    total = len(plan.steps)
    for number, step in enumerate(plan.steps, 1):
        progress(f"[{number}/{total}] {step.id} …")
        journal.begin(step.id, ctx.clock())
        try:
            RUNNERS[step.kind](step, ctx)
        except LpamError as exc:
            journal.fail(step.id, ctx.clock(), exc.message)
            raise StepError(
                f"step {step.id} failed: {exc.message}. {_where(step.phase, ctx)}",
                hint=exc.hint or "fix the cause and run `lpam apply` again; it resumes here",
            ) from exc
        journal.end(step.id, ctx.clock())
    journal.close(ctx.clock())


def _where(phase: Phase, ctx: Context) -> str:
    if phase is Phase.PREPARE:
        return "Nothing was changed on the running app."
    app = ctx.record.app
    if app is None:
        return "No app is installed now."
    state = "running" if app.running else "installed, not running"
    return f"Installed now: {app.name} ({state})."
