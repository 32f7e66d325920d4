"""The health check of a started app (VERIFY): a failure raises HealthError, which rolls
the apply back; only a check that ran to its end makes the app good."""

from __future__ import annotations

from reconciler.base.errors import HealthError
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps.folders import installed, of_record, place
from reconciler.engine.execution.supervision import log_tail, settle
from schemas.plan import HealthCheck, VerifyStep
from schemas.record import AppRecord


def verify(step: VerifyStep, ctx: Context) -> None:
    """The health check: the unit stays active `settle_seconds` without restarting, then
    `health.command` (when given) exits 0 within its timeout. HealthError rolls back."""
    app = installed(step.app, step.id, ctx)
    health = step.health
    seconds = health.settle_seconds
    if app.service is not None and seconds > 0:
        settle(ctx, app, app.service, seconds)
    began = ctx.clock().timestamp() - seconds  # frames the app sent while it settled count
    command = health.command
    if command is not None:
        where = place(ctx, of_record(ctx, app))
        ok, output = ctx.scripts.check(app.name, where, list(command), app.params,
                                       timeout=health.timeout_seconds)
        if not ok:
            raise HealthError(
                f"{app.name}: its health check `{' '.join(command)}` failed: {output}",
                hint="fix the app (or its health settings) and apply again",
                details=log_tail(ctx, app.service))
    _heard_on_bus(health, ctx, app, began)
    _proved(ctx, app)


def _heard_on_bus(health: HealthCheck, ctx: Context, app: AppRecord, began: float) -> None:
    """`health.can`: the app must put each of its ids on the bus; one missing fails health
    (and the apply rolls back). Read from the desired state's vehicle source."""
    ids, within = health.can_ids, health.can_within_seconds
    if not ids:
        return
    if ctx.listener is None:
        raise HealthError(f"{app.name}: its health check needs the CAN bus, and this "
                          "command reads none", hint="apply the desired state that "
                          "declares the vehicle source")
    missing = sorted(set(ids) - ctx.listener.heard(ids, since=began, within=within))
    if missing:
        raise HealthError(
            f"{app.name}: did not put {', '.join(f'0x{i:X}' for i in missing)} on the CAN "
            f"bus within {within:g} s of starting",
            hint="check that the app talks to the bus (and the vehicle source lpam reads), "
            "or its health.can settings", details=log_tail(ctx, app.service))


def _proved(ctx: Context, app: AppRecord) -> None:
    """The health check ran to its end and passed: from now on the app is good (a
    rollback target, an apply that is `applied`). Nothing before this point may say so."""
    current = ctx.record.installed(app.name)
    if current is not None and current.generation == app.generation:
        ctx.save_app(app.name, current.model_copy(update={"good": True}))
