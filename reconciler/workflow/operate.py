"""Operator commands on the installed apps — `lpam start|stop|restart [APP]|rollback` — run
as journalled plans through the same executor as every apply.

They are what LPAM's `-s`/`-k` and the field tool's `As`/`Ar` did, made safe: under the
apply lock, by the planner's rules (a cut-off script is finished first, nothing starts
beside a stray), and written down. An operator's stop *holds*: the record marks the app
`held`, and plans leave it stopped until `lpam start` or a change of the desired state.
With several apps installed, a name picks one app and its steps touch no other app's
process; no name works on every installed app. A hold belongs to each app.
A rollback returns to the previous good generation with no network, and holds too: until
the desired state changes, plan and apply report it and propose nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from reconciler import __version__
from reconciler.base.errors import LpamError
from reconciler.base.layout import KEEP_GENERATIONS
from reconciler.core.documents import load_desired
from reconciler.core.planning.holds import fingerprint, release_command, same_set
from reconciler.core.planning.model import GenerationKey
from reconciler.core.planning.modes import operator_plan, rollback_plan
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.executor import execute
from reconciler.engine.execution.lock import apply_lock
from reconciler.engine.records import generations
from reconciler.workflow.applying import ApplyOptions, installed_apps
from reconciler.workflow.events import Progress, Report
from reconciler.workflow.gates import governing
from reconciler.workflow.machine import Machine
from schemas.desired import DesiredState
from schemas.operator import OperatorAction
from schemas.plan import StartStep, Step
from schemas.record import AppRecord, HistoryEntry, Hold, StateRecord, history_sets

ProgressLine = Callable[[str], None]


def operate_installed(machine: Machine, action: OperatorAction, *, file: Path | None,
                      force: bool, options: ApplyOptions, report: Report,
                      app: str | None = None) -> str:
    """`lpam start|stop|restart [APP]`: under the apply lock, obeying the gates of the
    desired state in force (workflow/gates.py) unless `force`; returns what was done.
    `app`: that installed app only; None: every installed app."""
    gate = governing(machine, file, force=force).gate
    with apply_lock(machine.layout, timeout=options.lock_wait()) as lock:
        ctx, _ = machine.context(machine.store(), lock, command=str(action),
                                 script_timeout=options.script_timeout, report=report,
                                 gate=gate, gate_wait=options.wait, by=options.by,
                                 why="operator")
        return operate(ctx, action, progress=lambda text: report(Progress(text)), app=app)


def resumed_by(command: str) -> str:
    """The command that goes on from where `command` was cut off. A rollback holds the
    generation it returns to from its first change, so an apply finishes it; another
    rollback would go one generation further back. The agent's work is one sync pass."""
    return {"rollback": "apply", "agent": "sync"}.get(command, command)


def roll_back(machine: Machine, *, file: Path | None, force: bool, options: ApplyOptions,
              confirm: Callable[[list[HistoryEntry]], bool], report: Report) -> str | None:
    """`lpam rollback`: under the apply lock, the previous good set of apps is found and
    `confirm`ed, then made current (see `rollback`); None when it was declined. It holds
    against `file` (else the default file) when no apply recorded what it applied."""
    path = file if file is not None else machine.layout.desired_state
    desired = load_desired(path) if path.exists() else None
    gate = governing(machine, file, force=force).gate
    with apply_lock(machine.layout, timeout=options.lock_wait()) as lock:
        # what resumes a cut-off rollback is an apply, not another rollback (resumed_by)
        ctx, _ = machine.context(machine.store(), lock, command=resumed_by("rollback"),
                                 script_timeout=options.script_timeout, report=report,
                                 gate=gate, gate_wait=options.wait, by=options.by,
                                 why="rollback")
        entries = previous_good(ctx)
        kept = stays_stopped(ctx.record, entries)
        if kept:  # said before the question: the answer covers it
            report(Progress(kept))
        if not confirm(entries):
            return None
        return rollback(ctx, entries, desired, progress=lambda text: report(Progress(text)))


def stays_stopped(record: StateRecord, entries: list[HistoryEntry]) -> str:
    """The apps an operator stopped that a rollback to `entries` leaves stopped (an
    operator's stop holds through a rollback: it restores generations and parameters,
    and starts no app the operator stopped), and how to start them; "" when none."""
    back = {e.app for e in entries}
    held = [a.name for a in record.apps if a.held and a.name in back]
    if not held:
        return ""
    one = len(held) == 1
    start = f"`lpam start {held[0]}`" if one else \
        "`lpam start` (or `lpam start APP`) starts them"
    return (f"{', '.join(held)} {'was' if one else 'were'} stopped by an operator (`lpam "
            f"stop`) and {'stays' if one else 'stay'} stopped after the rollback: "
            f"{start + ' starts it' if one else start}.")


def operate(ctx: Context, action: OperatorAction, *, progress: ProgressLine,
            app: str | None = None) -> str:
    """Start, stop or restart installed apps now — `app` only, else every installed app —
    and return what was done. An operator's stop holds each app it stopped, and only it."""
    chosen = chosen_apps(ctx.record, app, action)
    names = [a.name for a in chosen]
    with gates_passed(ctx, progress):
        # The operator's wish is written first, so that a fault cannot undo it: the next
        # run carries out a stop (or a start) that was asked for and cut off.
        for one in chosen:
            if action == OperatorAction.STOP:
                ctx.save_app(one.name, one.model_copy(update={"held": True,
                                                              "held_by": ctx.by}))
            elif one.held:
                ctx.save_app(one.name, one.model_copy(update={"held": False,
                                                              "held_by": None}))
        made = operator_plan(ctx.record, action, generations.present(ctx.layout),
                             chosen=names, now=ctx.clock(), lpam_version=__version__)
        if made.steps:
            execute(made, ctx, progress=progress, record_result=False)
    return _done(action, names, made.steps)


def chosen_apps(record: StateRecord, name: str | None,
                action: OperatorAction) -> list[AppRecord]:
    """The installed apps an operator's command works on (`installed_apps`)."""
    return installed_apps(record, name, f"nothing to {action}")


def _done(action: OperatorAction, names: list[str], steps: list[Step]) -> str:
    """What an operator's command did to its apps: an app not started by it was already
    running (one app alone was started by any step)."""
    if action == OperatorAction.STOP:
        until = "it stays stopped until `lpam start`" if len(names) == 1 else \
            "each stays stopped until `lpam start` (or `lpam start APP`)"
        return f"Stopped {', '.join(names)}; {until} or a change of the desired state."
    verb = "Restarted" if action == OperatorAction.RESTART else "Started"
    moved = {s.app.name for s in steps if isinstance(s, StartStep)} if len(names) > 1 \
        else set(names) if steps else set()
    done = [n for n in names if n in moved]
    idle = [n for n in names if n not in moved]
    said = [f"{verb} {', '.join(done)}."] if done else []
    said += [f"{', '.join(idle)} {'is' if len(idle) == 1 else 'are'} already running."] \
        if idle else []
    return " ".join(said)


@contextmanager
def gates_passed(ctx: Context, progress: ProgressLine) -> Iterator[None]:
    """An operator command obeys the update gates (unless --force, which gives none): they
    are passed before anything is written — a stop's hold mark included — and their locks
    held to the end. Closed: `Deferred`, and nothing changed."""
    gate = ctx.gate
    if gate is None:
        yield
        return
    held = gate.hold(wait=ctx.gate_wait, progress=progress)
    ctx.gate = None  # passed: the executor need not ask again
    try:
        yield
    finally:
        ctx.gate = gate
        held.release()


def previous_good(ctx: Context) -> list[HistoryEntry]:
    """The last good set of apps (the history's sets: schemas/record.py `history_sets`)
    other than the one installed, every generation of it still on disk."""
    present = generations.present(ctx.layout)
    for entries in reversed(history_sets(ctx.record.history)):
        if entries[0].result != "applied" or same_set(entries, ctx.record.apps):
            continue
        if all(GenerationKey.of(e.app, e.generation) in present for e in entries):
            return entries
    raise LpamError("no previous good generation is kept on disk to roll back to",
                    hint="see `lpam history`; lpam keeps the last good generations on disk "
                    f"({KEEP_GENERATIONS}, or as many as `--keep-generations` said)")


def rollback(ctx: Context, entries: list[HistoryEntry], desired: DesiredState | None, *,
             progress: ProgressLine) -> str:
    """Make `entries` (a set of apps) current again through
    journalled steps, and hold them there. The hold is written first: if lpam dies
    mid-rollback, the next plan finishes it (workflow.planning). It holds against the
    desired state last applied, whichever file or revision that came from (`desired`, the
    default file's, counts only when no apply recorded one)."""
    applied = ctx.record.desired
    hold = Hold(desired=applied.fingerprint if applied is not None
                else fingerprint(desired), targets=entries, by=ctx.by)
    kept = stays_stopped(ctx.record, entries)
    stopped = {a.name: a.held_by for a in ctx.record.apps if a.held}
    with gates_passed(ctx, progress):
        ctx.save(ctx.record.model_copy(update={"hold": hold}))
        made = rollback_plan(ctx.record, entries, generations.present(ctx.layout),
                             now=ctx.clock(), lpam_version=__version__)
        if made.steps:
            execute(made, ctx, progress=progress, record_result=False)
        for app in ctx.record.apps:  # a generation installed anew keeps the operator's stop
            if app.name in stopped and not app.held:
                ctx.save_app(app.name, app.model_copy(update={"held": True,
                                                              "held_by": stopped[app.name]}))
    said = ", ".join(f"{e.app} ({e.generation}, commit {e.commit[:12]})" for e in entries)
    return (f"Rolled back to {said}. "
            f"{'It holds' if len(entries) == 1 else 'They hold'}: plan and apply propose "
            f"nothing until the desired state changes (or `{release_command(ctx.record)}`)."
            + (f" {kept}" if kept else ""))
