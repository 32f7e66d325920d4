"""When a cutover fails or was cut off: the good app to return to, the rollback, and the
record of how the apply ended — written so that no fault can make lpam forget them.

The record's `cutover` (schemas/record.py) is written before the first cutover step and
holds the *good* app the apply returns to if the new one fails (RAUC: a slot is good only
once it proved good). A kill mid-cutover leaves it there, so the apply that resumes still
knows where to go back, even though the record's app is now the unproven new one. Before
an automatic rollback runs, its failure is written into it too: a rollback that a fault
cut off is finished by the next run (workflow/planning.py plans its steps), which then
records the failure in history and status as if the rollback had never been interrupted.

The state record is how lpam knows what it did, so a step whose intent cannot be written
does no work. When the record cannot be written at all (a full disk), what stands on disk
is still exact: the error says what it shows and what the next apply will do from there.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import timedelta

from reconciler.base.errors import (
    Deferred,
    HealthError,
    LpamError,
    StateWriteError,
    StepError,
)
from reconciler.core.planning.holds import same_set
from reconciler.core.planning.lifecycle import resume_text
from reconciler.core.planning.model import GenerationKey
from reconciler.core.planning.modes import names, steps_back
from reconciler.core.planning.settling import owed
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps import run
from reconciler.engine.records.journal import Journal
from reconciler.engine.records.state import read_record
from schemas.enums import StrEnum
from schemas.plan import Phase, Step
from schemas.record import (
    Actor,
    ApplyResult,
    AppRecord,
    Cutover,
    DesiredRef,
    HistoryEntry,
    Hold,
    LastApply,
    Rollback,
    StateRecord,
    history_sets,
)

Progress = Callable[[str], None]


class AdvisoryJournal:
    """The journal as the executor writes it mid-apply: advisory, so a write that fails
    (a full disk, a path made a directory or a link) is reported once and the apply goes
    on — the state record, written before each step's work, is what lpam trusts."""

    def __init__(self, journal: Journal, warn: Progress) -> None:
        self._journal = journal
        self._warn = warn
        self.problem: str | None = None

    def _write(self, write: Callable[[], None]) -> None:
        try:
            write()
        except (OSError, LpamError) as exc:
            self._failed(exc)

    def _failed(self, exc: OSError | LpamError) -> None:
        if self.problem is None:
            self.problem = exc.message if isinstance(exc, LpamError) else \
                f"{exc.strerror or exc}"
            self._warn(f"note: the apply journal could not be written ({self.problem}); "
                       "the apply goes on: the state record keeps where it stands")

    def open(self, ctx: Context) -> None:
        """A fresh journal for this apply. Whatever stands in its place and cannot be moved
        aside is a ConfigError (nothing was done yet); a failing write is advisory."""
        try:
            self._journal.open(ctx.clock(), warn=self._warn)
        except OSError as exc:
            self._failed(exc)

    def begin(self, step: str, ctx: Context) -> None:
        self._write(lambda: self._journal.begin(step, ctx.clock()))

    def end(self, step: str, ctx: Context) -> None:
        self._write(lambda: self._journal.end(step, ctx.clock()))

    def fail(self, step: str, ctx: Context, message: str) -> None:
        self._write(lambda: self._journal.fail(step, ctx.clock(), message))

    def defer(self, ctx: Context, reason: str) -> None:
        self._write(lambda: self._journal.defer(ctx.clock(), reason))

    def close(self, ctx: Context) -> None:
        self._write(lambda: self._journal.close(ctx.clock()))


def journalled(step: Step, label: str, ctx: Context, journal: AdvisoryJournal) -> None:
    """One step's work between its journal lines."""
    journal.begin(label, ctx)
    try:
        run(step, ctx)
    except LpamError as exc:
        journal.fail(label, ctx, exc.message)
        raise
    journal.end(label, ctx)


def returns_to(record: StateRecord, layout_generations: frozenset[GenerationKey]
               ) -> list[AppRecord]:
    """The good apps a failing apply goes back to: the ones its interrupted predecessor
    recorded; else each installed app if it proved good, else the newest good generation
    of that app in the history still on disk; else (nothing good is known) the installed
    app as it is."""
    if record.cutover is not None:
        return list(record.cutover.previous)
    back = []
    for app in record.apps:
        entry = None if app.good else next(
            (e for e in reversed(record.history) if e.result == "applied"
             and e.app == app.name
             and GenerationKey.of(e.app, e.generation) in layout_generations), None)
        back.append(app if entry is None else entry.installed())
    return back


def begun(ctx: Context) -> StateRecord:
    """The record as an apply begins: its result `in progress` (with this process, so one
    that is gone reads as cut off) and the desired state it works toward."""
    last = LastApply(time=ctx.clock().isoformat(timespec="seconds"), result="in progress",
                     pid=os.getpid(), command=ctx.command, by=ctx.by)
    return ctx.record.model_copy(update={"last_apply": last,
                                         "desired": ctx.desired or ctx.record.desired})


def interrupted(ctx: Context) -> None:
    """Ctrl-C or SIGTERM: say so in the record (best effort: it is how the apply ended)."""
    last = LastApply(time=ctx.clock().isoformat(timespec="seconds"), result="interrupted",
                     reason="by Ctrl-C or SIGTERM; where it stood is recorded",
                     command=ctx.command, by=ctx.by)
    with contextlib.suppress(LpamError):
        ctx.save(ctx.record.model_copy(update={"last_apply": last}))


DEFERRED_PREFIX = "the update gates are closed: "  # how the gates word a deferral


def deferred(ctx: Context, exc: Deferred, *, desired: DesiredRef | None) -> None:
    """A closed gate ended the apply before its cutover: say so in the record, with the
    gates that were closed and when the agent's next pass tries again (best effort, as an
    interruption). No command is kept: the desired state to apply next time may no
    longer be this one. Nothing on the running app changed, so the desired state in force
    stays the one before it (`desired`: what holds hold against — an operator's stop
    must not end because an apply of another file was deferred)."""
    now = ctx.clock()
    reason = exc.message[len(DEFERRED_PREFIX):] if exc.message.startswith(DEFERRED_PREFIX) \
        else exc.message
    retry = None if ctx.retry_after is None else \
        (now + timedelta(seconds=ctx.retry_after)).isoformat(timespec="seconds")
    last = LastApply(time=now.isoformat(timespec="seconds"), result="deferred",
                     reason=reason, gates=list(exc.gates), retry=retry, by=ctx.by)
    with contextlib.suppress(LpamError):
        ctx.save(ctx.record.model_copy(update={"last_apply": last, "desired": desired}))


def settled(record: StateRecord, *, now: str, desired: DesiredRef | None,
            by: Actor | None = None) -> StateRecord | None:
    """The record after an apply that had nothing to do (None: nothing to write). The
    machine matched the desired state in force, so a deferred, interrupted or cut-off
    apply before it no longer applies: status must not keep telling the user to resume
    it. A cutover that was cut off after its last step ends too (a rollback still owed is
    finished by its own plan, never here); what the checkouts hold is what runs."""
    owes = owed(record) is not None  # what the plan said it ends (core/planning/settling)
    # A rollback's hold ends when the desired state changes; an apply of another desired
    # state that the car already matches has nothing to do, and ends it all the same.
    hold = record.hold if record.hold is None or desired is None \
        or record.hold.desired == desired.fingerprint else None
    if not owes and hold == record.hold:
        return None
    # Under a rollback's hold nothing to do means the car is what the rollback returned to,
    # not what the checkouts hold.
    repositories = record.repositories if hold is not None else \
        [r.model_copy(update={"applied": r.commit}) for r in record.repositories]
    # Under holds the car differs from the desired state on purpose: never "it matched"
    held = hold is not None or any(a.held for a in record.apps)
    why = "the holds in force keep the rest as it is" if held else \
        "the machine matched the desired state"
    return record.model_copy(update={
        "last_apply": LastApply(time=now, result="applied",
                                reason=f"nothing was left to do: {why}", by=by),
        "repositories": repositories,
        "cutover": None,
        "desired": desired or record.desired,
        "hold": hold,
    })


def begin_cutover(ctx: Context, previous: list[AppRecord]) -> None:
    """Written before the first cutover step; an earlier one (cut off) is kept."""
    if ctx.record.cutover is None:
        began = ctx.clock().isoformat(timespec="seconds")
        ctx.save(ctx.record.model_copy(
            update={"cutover": Cutover(previous=previous, began=began)}))


def pending(record: StateRecord) -> Rollback | None:
    """The automatic rollback a fault cut off, which this run finishes."""
    return record.cutover.rollback if record.cutover is not None else None


class Outcome(StrEnum):
    """How the return to the app that ran before ended: what is decided on (the apply is
    `rolled back` only when the car is back), never the text said about it."""

    NONE = "none"  # nothing to roll back: the failure was before the cutover, or no step
    BACK = "back"  # the previous app (or no app) is back
    FAILED = "failed"  # the rollback failed too


@dataclass(frozen=True)
class RollbackResult:
    outcome: Outcome
    said: str = ""  # what happened, to add to the failure's message


def roll_back(failed: Step, exc: LpamError, previous: list[AppRecord], ctx: Context,
              journal: AdvisoryJournal, progress: Progress, *, record_result: bool
              ) -> RollbackResult:
    """After a failed cutover step, go back to the apps that ran before: every change of
    the apply is undone (core/planning/ensemble.py orders it by what the apps claim). The
    rollback is written down before it begins."""
    if failed.phase is not Phase.CUTOVER:
        return RollbackResult(Outcome.NONE)
    steps = steps_back(ctx.record, previous, ctx.app_folders().present())
    if not steps:
        return RollbackResult(Outcome.NONE)
    what = f"rolling back to {names(previous)}" if previous else \
        "removing the half-installed app"
    try:
        if record_result and pending(ctx.record) is None:
            _note_rollback(ctx, previous, f"step {failed.id} failed: {exc.message}",
                           health=isinstance(exc, HealthError))
        progress(f"{what} …")
        ctx.why = "rollback"  # what its steps start and stop, the timeline says why
        for step in steps:
            progress(f"  rollback: {step.id} …")
            journalled(step, f"rollback/{step.id}", ctx, journal)
    except LpamError as again:
        return RollbackResult(Outcome.FAILED, f" {what.capitalize()} failed too: "
                              f"{again.message}.")
    return RollbackResult(Outcome.BACK, f" Rolled back to {names(previous)}." if previous
                          else " Removed the new app again.")


def changed(record: StateRecord, previous: list[AppRecord]) -> list[AppRecord]:
    """The installed apps an apply changed: not as they were before it (its failures)."""
    before = {(p.name, p.generation, tuple(sorted(p.params.items()))) for p in previous}
    return [a for a in record.apps
            if (a.name, a.generation, tuple(sorted(a.params.items()))) not in before]


def _note_rollback(ctx: Context, previous: list[AppRecord], reason: str, *,
                   health: bool) -> None:
    cutover = ctx.record.cutover or Cutover(
        previous=previous, began=ctx.clock().isoformat(timespec="seconds"))
    rollback = Rollback(failed=changed(ctx.record, previous), reason=reason, health=health,
                        time=ctx.clock().isoformat(timespec="seconds"))
    ctx.save(ctx.record.model_copy(
        update={"cutover": cutover.model_copy(update={"rollback": rollback})}))


def fail(step: Step, exc: LpamError, previous: list[AppRecord], ctx: Context,
         journal: AdvisoryJournal, progress: Progress, *, record_result: bool) -> LpamError:
    """Roll back if the cutover had begun, record how the apply ended; the error to raise."""
    attempted = changed(ctx.record, previous)
    rolled = roll_back(step, exc, previous, ctx, journal, progress,
                       record_result=record_result)
    back = rolled.outcome is Outcome.BACK
    message = f"step {step.id} failed: {exc.message}.{rolled.said} {where(step.phase, ctx)}"
    hint = exc.hint or f"fix the cause and run `{ctx.command}` again; it resumes here"
    try:
        if record_result:
            earlier = pending(ctx.record)
            finish(ctx, "rolled back" if back else "failed", message,
                   failed=(earlier.failed if earlier else attempted) if back else [])
    except StateWriteError as unwritable:
        return unwritable_error(ctx, unwritable)
    if isinstance(exc, StateWriteError):
        return unwritable_error(ctx, exc)
    error = HealthError if isinstance(exc, HealthError) else StepError
    return error(message, hint=hint, details=exc.details)


def finish_pending(ctx: Context, rollback: Rollback, previous: list[AppRecord]) -> LpamError:
    """A rollback that a fault cut off is finished: record it as the apply that began it
    would have, and report the failure that caused it (never success)."""
    back = f"rolled back to {names(previous)}" if previous else "removed the new app again"
    message = (f"{rollback.reason}. The rollback was cut off by a fault; this run finished "
               f"it: {back}. {where(Phase.CUTOVER, ctx)}")
    try:
        finish(ctx, "rolled back", message, failed=rollback.failed)
    except StateWriteError as unwritable:
        return unwritable_error(ctx, unwritable)
    error = HealthError if rollback.health else StepError
    return error(message, hint="fix the app (or its health settings) and apply again")


def hold_after(record: StateRecord, result: ApplyResult,
               desired: DesiredRef | None = None) -> Hold | None:
    """An apply that installs something other than what a rollback returned to ends the
    hold, and so does one of a desired state other than the one held against (`desired`:
    what this apply worked toward) even if it installs just that; the apply that finished
    a cut-off rollback keeps it."""
    hold = record.hold
    if hold is None or result != "applied":
        return hold
    if desired is not None and desired.fingerprint != hold.desired:
        return None
    return hold if record.apps and same_set(hold.targets, record.apps) else None


def finish(ctx: Context, result: ApplyResult, reason: str | None, *,
           failed: Sequence[AppRecord] = ()) -> None:
    """Record how the apply ended, and the generations it made current (history: the
    entries of one apply carry its number, a set, and who asked for it). A generation
    enters the history as
    applied only once it proved good. The cutover ends with the apply, unless it failed
    mid-way: then the next run still needs it."""
    when = ctx.clock().isoformat(timespec="seconds")
    apply = ctx.record.serial  # one number per apply: its entries are one set
    history = [*ctx.record.history,
               *(HistoryEntry.of(app, time=when, result="rolled back", apply=apply,
                                 by=ctx.by)
                 for app in failed)]
    made = [app for app in ctx.record.apps if app.good]
    last = next((s for s in reversed(history_sets(history)) if s[0].result == "applied"), [])
    if result == "applied" and made and not same_set(last, made):
        history += [HistoryEntry.of(app, time=when, result="applied", apply=apply,
                                    by=ctx.by)
                    for app in made]
    repositories = ctx.record.repositories
    if result == "applied":  # what runs now is what these checkouts hold
        repositories = [r.model_copy(update={"applied": r.commit}) for r in repositories]
    ctx.save(ctx.record.model_copy(update={
        "last_apply": LastApply(time=when, result=result, reason=reason,
                                command=None if result == "applied" else ctx.command,
                                by=ctx.by),
        "repositories": repositories,
        "history": [e for s in history_sets(history)[-KEEP_SETS:] for e in s],
        "hold": hold_after(ctx.record, result, ctx.desired),
        "cutover": ctx.record.cutover if result == "failed" else None,
    }))


KEEP_SETS = 20  # the sets of apps `lpam history` remembers


def where(phase: Phase, ctx: Context) -> str:
    if phase is Phase.PREPARE:
        return "Nothing was changed on the running app."
    if not ctx.record.apps:
        return "No app is installed now."
    states = [f"{app.name} (" + {"running": "running", "installed": "installed, not running"}
              .get(app.status, f"{app.status} when the script failed") + ")"
              for app in ctx.record.apps]
    return f"Installed now: {', '.join(states)}."


def unwritable_error(ctx: Context, exc: StateWriteError) -> StateWriteError:
    """The state record cannot be written: no step did work it could not record, so the
    record on disk is exact. Say what it shows and what the next apply does from it."""
    try:
        record = read_record(ctx.layout)
    except LpamError:
        record = ctx.record
    if exc.explained:
        return exc
    error = StateWriteError(
        f"{exc.message}. lpam stopped there: no step did work it could not record. "
        f"{resume_text(record)}",
        path=exc.path,
        hint=f"free space (or fix the permissions) under {exc.path.parent if exc.path else '/'}"
        f", then run `{ctx.command}`: it goes on from what the record shows",
    )
    error.explained = True
    return error
