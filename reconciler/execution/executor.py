"""Run a plan's steps in order, journalling each one before and after its work.

A failed step stops the apply at once with a message that says where the vehicle stands.
A failure while preparing left the running app untouched. A failure in the cutover rolls
back: the new app's half-install is uninstalled and the previous generation (kept until
the apply succeeds) is installed and started again, so a broken app never leaves the car
with nothing. A power cut, by contrast, is resumed forward: the next apply re-plans from
the state record and continues where this one stopped.
"""

from __future__ import annotations

import contextlib
import uuid
from collections.abc import Callable

from reconciler.errors import LpamError, StepError
from reconciler.execution.journal import Journal
from reconciler.execution.steps import RUNNERS, Context, prune_generations, reinstall
from schemas.plan import Phase, Plan, Step, StepKind
from schemas.record import AppRecord


def execute(plan: Plan, ctx: Context, *, progress: Callable[[str], None]) -> None:
    journal = Journal(ctx.layout, apply_id=str(uuid.uuid4()), plan=plan.fingerprint)
    journal.open(ctx.clock())
    previous = ctx.record.app
    total = len(plan.steps)
    for number, step in enumerate(plan.steps, 1):
        progress(f"[{number}/{total}] {step.id} …")
        journal.begin(step.id, ctx.clock())
        try:
            RUNNERS[step.kind](step, ctx)
        except LpamError as exc:
            journal.fail(step.id, ctx.clock(), exc.message)
            rolled = _roll_back(step, previous, ctx, progress)
            raise StepError(
                f"step {step.id} failed: {exc.message}.{rolled} {_where(step.phase, ctx)}",
                hint=exc.hint or "fix the cause and run `lpam apply` again; it resumes here",
            ) from exc
        journal.end(step.id, ctx.clock())
    journal.close(ctx.clock())
    prune_generations(ctx)


def _roll_back(
    step: Step, previous: AppRecord | None, ctx: Context, progress: Callable[[str], None]
) -> str:
    """After a failed cutover step, bring back the app that ran before; says what happened."""
    if step.phase is not Phase.CUTOVER or previous is None or ctx.record.app == previous:
        return ""
    progress(f"rolling back to {previous.name} …")
    try:
        if step.kind is StepKind.INSTALL:  # undo what a half-finished install.sh left
            app, generation = str(step.args["app"]), str(step.args["generation"])
            params = step.args.get("params")
            with contextlib.suppress(LpamError):  # best effort: it may have left nothing
                ctx.scripts.run(app, ctx.layout.generation_dir(app, generation),
                                "uninstall.sh", params if isinstance(params, dict) else {})
        reinstall(previous, ctx)
    except LpamError as again:
        return f" Rolling back to {previous.name} failed too: {again.message}."
    return f" Rolled back to {previous.name}."


def _where(phase: Phase, ctx: Context) -> str:
    if phase is Phase.PREPARE:
        return "Nothing was changed on the running app."
    app = ctx.record.app
    if app is None:
        return "No app is installed now."
    state = "running" if app.running else "installed, not running"
    return f"Installed now: {app.name} ({state})."
