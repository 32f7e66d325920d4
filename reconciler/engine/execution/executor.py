"""Run a plan's steps in order, journalling each one before and after its work.

A failed step stops the apply at once with a message that says where the vehicle stands.
A failure while preparing left the running app untouched. A failure in the cutover rolls
back (engine/execution/recovery.py): the steps back to the good apps that ran before are
planned by the same rules as any plan (core/planning/modes.py `steps_back`: whatever the
new app may have started is stopped before it is uninstalled; an old app whose
uninstall.sh failed is installed again rather than uninstalled twice) and journalled like
any step, so the car is never left with two apps nor, when the old one can run, with none.
With no previous app, the half-installed new one is removed. A power cut or a kill, by
contrast, is resumed forward: the next apply re-plans from the state record and continues
where this one stopped — verifying an app whose health check did not run to its end, and
finishing a rollback that had begun, toward the good app the record's `cutover` names.
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable
from concurrent.futures import CancelledError, ThreadPoolExecutor

from reconciler.base.errors import Deferred, LpamError, StateWriteError, StopRequested, Terminated
from reconciler.base.layout import KEEP_GENERATIONS
from reconciler.engine.execution.collection import prune
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.ports import Gate, Held
from reconciler.engine.execution.recovery import (
    AdvisoryJournal,
    begin_cutover,
    begun,
    deferred,
    fail,
    finish,
    finish_pending,
    interrupted,
    journalled,
    pending,
    returns_to,
    unwritable_error,
)
from reconciler.engine.execution.steps import check_out, record_checkout
from reconciler.engine.records.journal import Journal
from schemas.generation import AppGeneration
from schemas.plan import CheckoutStep, Phase, Plan, Step
from schemas.record import AppRecord

CHECKOUT_WORKERS = 4  # checkouts wait on the disk more than on the CPU


def execute(plan: Plan, ctx: Context, *, progress: Callable[[str], None],
            record_result: bool = True, keep: int = KEEP_GENERATIONS) -> None:
    """Run `plan`; `record_result` writes how it ended and its generation to the record
    (an apply's; an operator's stop or start is not an apply). `keep` good generations
    stay on disk for `lpam rollback`."""
    journal = AdvisoryJournal(
        Journal(ctx.layout, apply_id=str(uuid.uuid4()), plan=plan.fingerprint), progress)
    journal.open(ctx)
    in_force = ctx.record.desired  # a deferral changes nothing: it stays in force
    try:
        _execute(plan, ctx, journal, progress, record_result=record_result, keep=keep)
    except StateWriteError as exc:  # a full disk: say where the record left the car
        raise unwritable_error(ctx, exc) from None
    except Deferred as exc:  # a closed gate: deferred, never taken for a kill
        if record_result:
            deferred(ctx, exc, desired=in_force)
        raise
    except (KeyboardInterrupt, Terminated):
        if record_result:
            interrupted(ctx)
        raise


def _execute(plan: Plan, ctx: Context, journal: AdvisoryJournal,
             progress: Callable[[str], None], *, record_result: bool, keep: int) -> None:
    # As read (settled, strays adopted) — before any exit file is pruned; an apply says
    # from its start that it is under way, and toward which desired state.
    ctx.save(begun(ctx) if record_result else ctx.record)
    previous = returns_to(ctx.record, ctx.app_folders().present()) if record_result \
        else list(ctx.record.apps)
    cut_off = pending(ctx.record) if record_result else None
    held: list[Held] = []
    try:
        _run(plan, ctx, journal, progress, previous=previous, record_result=record_result,
             held=held)
    finally:
        for lock in held:
            lock.release()
    journal.close(ctx)
    if cut_off is not None:  # the steps that finish a rollback ran: it ends as it began
        raise finish_pending(ctx, cut_off, previous)
    if record_result:  # an operator's start, stop or rollback makes no generation
        finish(ctx, "applied", None)
        prune(ctx, keep=keep)


def _run(plan: Plan, ctx: Context, journal: AdvisoryJournal, progress: Callable[[str], None],
         *, previous: list[AppRecord], record_result: bool, held: list[Held]) -> None:
    """The steps in order; the gates are passed (and their locks added to `held`) just
    before the first cutover step, and the cutover is written down before it begins."""
    total = len(plan.steps)
    number = 0
    began = False
    while number < total:
        step = plan.steps[number]
        if step.phase is not Phase.CUTOVER and ctx.stop_requested():
            # A cutover that started is never interrupted; before it, stopping is safe.
            journal.close(ctx)
            raise StopRequested(f"stopped on request before {step.id}; nothing on the "
                                "running app was changed", hint="the next pass resumes")
        if step.phase is Phase.CUTOVER and not began:
            if ctx.gate is not None and gated(plan, ctx.gate):
                held.append(_pass_gates(ctx.gate, ctx, journal, progress))
            if record_result:
                begin_cutover(ctx, previous)  # StateWriteError: nothing was changed yet
            began = True
        batch = _checkouts_from(plan.steps, number)
        try:
            if len(batch) > 1:
                _checkouts(batch, number, total, ctx, journal, progress)
                number += len(batch)
                continue
            number += 1
            progress(f"[{number}/{total}] {step.id} …")
            journalled(step, step.id, ctx, journal)
        except _Failed as failed:
            raise fail(failed.step, failed.error, previous, ctx, journal, progress,
                       record_result=record_result) from failed.error
        except LpamError as exc:
            raise fail(step, exc, previous, ctx, journal, progress,
                       record_result=record_result) from exc


def gated(plan: Plan, gate: Gate) -> bool:
    """Whether the plan's cutover waits for the gates: always, unless the gates free the
    apps that claim nothing exclusive and every app (or stray) it touches claims nothing
    (an app whose claims are not known holds the panda)."""
    if not gate.unclaimed_free:
        return True
    apps = [getattr(step, "app", None) for step in plan.steps if step.phase is Phase.CUTOVER]
    return any(not isinstance(app, AppGeneration) or app.claims for app in apps)


def _pass_gates(gate: Gate, ctx: Context, journal: AdvisoryJournal,
                progress: Callable[[str], None]) -> Held:
    """Wait for the gates at the boundary of the cutover. Closed after the wait: the apply
    ends here, deferred — everything is prepared, nothing on the running app changed."""
    try:
        return gate.hold(wait=ctx.gate_wait, progress=progress)
    except Deferred as deferred:
        journal.defer(ctx, deferred.message)
        journal.close(ctx)
        raise


class _Failed(Exception):
    """A step of a batch of checkouts failed: which one, and why."""

    def __init__(self, step: Step, error: LpamError) -> None:
        super().__init__(error.message)
        self.step, self.error = step, error


def _checkouts_from(steps: list[Step], start: int) -> list[CheckoutStep]:
    """The run of checkouts that begins at `start` (empty if none does)."""
    batch: list[CheckoutStep] = []
    for step in steps[start:]:
        if not isinstance(step, CheckoutStep) or step.phase is not Phase.PREPARE:
            break
        batch.append(step)
    return batch


def _checkouts(batch: list[CheckoutStep], done: int, total: int, ctx: Context,
               journal: AdvisoryJournal, progress: Callable[[str], None]) -> None:
    """Several repositories checked out at once: each checkout writes only its own
    repository's files, and writing files is most of its time (half of a cold apply of 20
    repositories, docs/benchmarks.md). Each is journalled by its worker as it begins; its
    end, its record entry and its progress line follow in plan order, in this thread. A
    failure lets the checkouts already under way finish (and be recorded) and starts no
    more; the first failure in plan order is raised."""
    lock = threading.Lock()

    def work(step: CheckoutStep) -> None:
        with lock:
            journal.begin(step.id, ctx)
        check_out(step, ctx)

    first: _Failed | None = None
    with ThreadPoolExecutor(max_workers=CHECKOUT_WORKERS) as pool:
        futures = [pool.submit(work, step) for step in batch]
        for number, (step, future) in enumerate(zip(batch, futures), done + 1):
            try:
                future.result()
            except LpamError as exc:
                with lock:
                    journal.fail(step.id, ctx, exc.message)
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
                journal.end(step.id, ctx)
    if first is not None:
        raise first
