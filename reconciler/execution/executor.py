"""Run a plan's steps in order, journalling each one before and after its work.

A failed step stops the apply at once with a message that says where the vehicle stands.
A failure while preparing left the running app untouched. A failure in the cutover rolls
back: the steps back to the app that ran before are planned by the same rules as any plan
(planning/lifecycle.py: whatever the new app may have started is stopped before it is
uninstalled; an old app whose uninstall.sh failed is installed again rather than
uninstalled twice) and journalled like any step, so the car is never left with two apps
nor, when the old one can run, with none. With no previous app, the half-installed new one
is removed. A power cut or a kill, by contrast, is resumed forward: the next apply
re-plans from the state record and continues where this one stopped.
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable
from concurrent.futures import CancelledError
from typing import NoReturn

from reconciler import generations
from reconciler.errors import Deferred, HealthError, LpamError, StepError, StopRequested
from reconciler.execution.context import Context
from reconciler.execution.journal import Journal
from reconciler.execution.ports import Gate, Held
from reconciler.execution.steps import RUNNERS, check_out, prune, record_checkout
from reconciler.planning.lifecycle import app_steps, target_of
from schemas.plan import Phase, Plan, Step, StepKind
from schemas.record import ApplyResult, AppRecord, HistoryEntry, Hold, LastApply

KEEP_GENERATIONS = 3
CHECKOUT_WORKERS = 4  # checkouts wait on the disk more than on the CPU


def execute(plan: Plan, ctx: Context, *, progress: Callable[[str], None],
            record_result: bool = True, keep: int = KEEP_GENERATIONS) -> None:
    """Run `plan`; `record_result` writes how it ended and its generation to the record
    (an apply's; an operator's stop or start is not an apply). `keep` good generations
    stay on disk for `lpam rollback`."""
    journal = Journal(ctx.layout, apply_id=str(uuid.uuid4()), plan=plan.fingerprint)
    journal.open(ctx.clock(), warn=progress)
    ctx.save(ctx.record)  # as read: settled, strays adopted — before any exit file is pruned
    previous = ctx.record.app
    held: list[Held] = []
    try:
        _run(plan, ctx, journal, progress, previous=previous, record_result=record_result,
             held=held)
    finally:
        for lock in held:
            lock.release()
    journal.close(ctx.clock())
    if record_result:  # an operator's start, stop or rollback makes no generation
        _finish(ctx, "applied", None)
        prune(ctx, keep=keep)


def _run(plan: Plan, ctx: Context, journal: Journal, progress: Callable[[str], None], *,
         previous: AppRecord | None, record_result: bool, held: list[Held]) -> None:
    """The steps in order; the gates are passed (and their locks added to `held`) just
    before the first cutover step."""
    total = len(plan.steps)
    number = 0
    while number < total:
        step = plan.steps[number]
        if step.phase is not Phase.CUTOVER and ctx.stop_requested():
            # A cutover that started is never interrupted; before it, stopping is safe.
            journal.close(ctx.clock())
            raise StopRequested(f"stopped on request before {step.id}; nothing on the "
                                "running app was changed", hint="the next pass resumes")
        if step.phase is Phase.CUTOVER and not held and ctx.gate is not None:
            held.append(_pass_gates(ctx.gate, ctx, journal, progress))
        batch = _checkouts_from(plan.steps, number)
        try:
            if len(batch) > 1:
                _checkouts(batch, number, total, ctx, journal, progress)
                number += len(batch)
                continue
            number += 1
            progress(f"[{number}/{total}] {step.id} …")
            _journalled(step, step.id, ctx, journal)
        except _Failed as failed:
            _fail(failed.step, failed.error, previous, ctx, journal, progress, record_result)
        except LpamError as exc:
            _fail(step, exc, previous, ctx, journal, progress, record_result)


def _pass_gates(gate: Gate, ctx: Context, journal: Journal,
                progress: Callable[[str], None]) -> Held:
    """Wait for the gates at the boundary of the cutover. Closed after the wait: the apply
    ends here, deferred — everything is prepared, nothing on the running app changed."""
    try:
        return gate.hold(wait=ctx.gate_wait, progress=progress)
    except Deferred as deferred:
        journal.defer(ctx.clock(), deferred.message)
        journal.close(ctx.clock())
        raise


class _Failed(Exception):
    """A step of a batch of checkouts failed: which one, and why."""

    def __init__(self, step: Step, error: LpamError) -> None:
        super().__init__(error.message)
        self.step, self.error = step, error


def _checkouts_from(steps: list[Step], start: int) -> list[Step]:
    """The run of checkouts that begins at `start` (empty if none does)."""
    batch: list[Step] = []
    for step in steps[start:]:
        if step.kind is not StepKind.CHECKOUT or step.phase is not Phase.PREPARE:
            break
        batch.append(step)
    return batch


def _checkouts(batch: list[Step], done: int, total: int, ctx: Context, journal: Journal,
               progress: Callable[[str], None]) -> None:
    """Several repositories checked out at once: each checkout writes only its own
    repository's files, and writing files is most of its time (half of a cold apply of 20
    repositories, docs/benchmarks.md). Each is journalled by its worker as it begins; its
    end, its record entry and its progress line follow in plan order, in this thread. A
    failure lets the checkouts already under way finish (and be recorded) and starts no
    more; the first failure in plan order is raised."""
    from concurrent.futures import ThreadPoolExecutor

    lock = threading.Lock()

    def work(step: Step) -> None:
        with lock:
            journal.begin(step.id, ctx.clock())
        check_out(step, ctx)

    first: _Failed | None = None
    with ThreadPoolExecutor(max_workers=CHECKOUT_WORKERS) as pool:
        futures = [pool.submit(work, step) for step in batch]
        for number, (step, future) in enumerate(zip(batch, futures, strict=True), done + 1):
            try:
                future.result()
            except LpamError as exc:
                with lock:
                    journal.fail(step.id, ctx.clock(), exc.message)
                if first is None:
                    first = _Failed(step, exc)
                    for rest in futures:
                        rest.cancel()
                continue
            except CancelledError:
                continue
            progress(f"[{number}/{total}] {step.id} …")
            record_checkout(step, ctx)
            with lock:
                journal.end(step.id, ctx.clock())
    if first is not None:
        raise first


def _fail(step: Step, exc: LpamError, previous: AppRecord | None, ctx: Context,
          journal: Journal, progress: Callable[[str], None], record_result: bool) -> NoReturn:
    """Roll back if the cutover had begun, record how the apply ended, raise the error."""
    attempted = ctx.record.app
    rolled = _roll_back(step, previous, ctx, journal, progress)
    message = f"step {step.id} failed: {exc.message}.{rolled} {_where(step.phase, ctx)}"
    back = bool(rolled) and "failed too" not in rolled
    if record_result:
        _finish(ctx, "rolled back" if back else "failed", message,
                failed=attempted if back else None)
    error = HealthError if isinstance(exc, HealthError) else StepError
    raise error(
        message,
        hint=exc.hint or "fix the cause and run `lpam apply` again; it resumes here",
        details=exc.details,
    ) from exc


def _hold_after(ctx: Context, result: ApplyResult) -> Hold | None:
    """An apply that installs something other than what a rollback returned to ends the
    hold; the apply that finished a cut-off rollback keeps it."""
    hold, app = ctx.record.hold, ctx.record.app
    if hold is None or result != "applied":
        return hold
    return hold if app is not None and app.generation == hold.generation else None


def _finish(ctx: Context, result: ApplyResult, reason: str | None, *,
            failed: AppRecord | None = None) -> None:
    """Record how the apply ended, and the generation it made current (history)."""
    when = ctx.clock().isoformat(timespec="seconds")
    history = list(ctx.record.history)
    for app, outcome in ((failed, "rolled back"), (ctx.record.app, "applied")):
        if app is None or (outcome == "applied" and result != "applied"):
            continue
        last = next((h for h in reversed(history) if h.result == "applied"), None)
        if outcome == "applied" and last is not None and \
                (last.generation, last.params) == (app.generation, app.params):
            continue
        history.append(HistoryEntry.of(
            app, time=when, result="rolled back" if outcome == "rolled back" else "applied"))
    ctx.save(ctx.record.model_copy(update={
        "last_apply": LastApply(time=when, result=result, reason=reason),
        "history": history[-20:],
        "hold": _hold_after(ctx, result),
    }))


def _journalled(step: Step, label: str, ctx: Context, journal: Journal) -> None:
    journal.begin(label, ctx.clock())
    try:
        RUNNERS[step.kind](step, ctx)
    except LpamError as exc:
        journal.fail(label, ctx.clock(), exc.message)
        raise
    journal.end(label, ctx.clock())


def _roll_back(
    failed: Step, previous: AppRecord | None, ctx: Context, journal: Journal,
    progress: Callable[[str], None],
) -> str:
    """After a failed cutover step, go back to the app that ran before; says what happened."""
    if failed.phase is not Phase.CUTOVER:
        return ""
    target = None if previous is None else target_of(previous)
    # The car must not be left with no app: the previous one is started again unless an
    # operator had stopped it (after a crash its status may say `installing` though it ran).
    start = previous is None or not previous.held
    record, app = ctx.record, ctx.record.app
    if app is not None and previous is not None and app.status == "stopping" \
            and app.generation == previous.generation:
        # its stop.sh just failed: the old app is brought back up, not stopped again
        record = record.model_copy(update={"app": app.model_copy(update={"status": "starting"})})
    steps = app_steps(record, target, generations.present(ctx.layout), start=start,
                      verify=False)
    if not steps:
        return ""
    what = f"rolling back to {previous.name}" if previous else "removing the half-installed app"
    progress(f"{what} …")
    try:
        for step in steps:
            progress(f"  rollback: {step.id} …")
            _journalled(step, f"rollback/{step.id}", ctx, journal)
    except LpamError as again:
        return f" {what.capitalize()} failed too: {again.message}."
    return f" Rolled back to {previous.name}." if previous else " Removed the new app again."


def _where(phase: Phase, ctx: Context) -> str:
    if phase is Phase.PREPARE:
        return "Nothing was changed on the running app."
    app = ctx.record.app
    if app is None:
        return "No app is installed now."
    state = {"running": "running", "installed": "installed, not running"}.get(
        app.status, f"{app.status} when the script failed")
    return f"Installed now: {app.name} ({state})."
