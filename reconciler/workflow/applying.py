"""The apply use case: plan under the lock (fetching for real), confirm, execute.

Bad input is refused before the lock is taken, so it never waits on another apply; the
plan that is shown is the plan that runs, under the same lock. A saved plan runs only if
it is exact, untampered, and made against the state the machine is still in.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import LpamError, StateWriteError
from reconciler.base.layout import KEEP_GENERATIONS
from reconciler.workflow.defaults import LOCK_TIMEOUT, SCRIPT_TIMEOUT
from reconciler.workflow.events import Planned, Progress, Report
from reconciler.workflow.machine import Machine
from reconciler.workflow.planning import prepare

if TYPE_CHECKING:
    from reconciler.adapters.git import GitStore
    from reconciler.engine.execution.lock import Lock
    from reconciler.engine.execution.ports import Gate, Listener
    from reconciler.workflow.followed import Followed
    from schemas.desired import DesiredState
    from schemas.plan import Plan
    from schemas.record import Actor, AppRecord, DesiredRef, StateRecord

# Imported inside functions: the engine (planning, execution, records: pydantic) loads only
# when an apply runs; editing, agent, sync and BLE answers import this module (start-up).


@dataclass(frozen=True)
class ApplyOptions:
    lock_timeout: float | None = None  # None: each lock's own default (workflow.defaults)
    script_timeout: float = SCRIPT_TIMEOUT  # an app script running longer is killed
    keep_generations: int = KEEP_GENERATIONS  # good generations kept for `lpam rollback`
    release: bool = False  # end a rollback's hold first
    wait: float = 0.0  # seconds the cutover may wait for closed gates to open
    resume: str = "lpam apply"  # the command that resumes it, as the user would type it
    retry_after: float | None = None  # the agent's next pass tries a deferral again then
    # who asks (workflow/actor.py): written on what the change records; None: not known
    by: Actor | None = None

    def lock_wait(self, default: float = LOCK_TIMEOUT) -> float:
        """How long to wait for the apply lock: `--lock-timeout`, else `default`."""
        return default if self.lock_timeout is None else self.lock_timeout


@dataclass(frozen=True)
class Applied:
    """How an apply ended: `steps` run (0: nothing to do), the app as it stands now, and
    the log of its scripts and commands. `cancelled`: the caller declined the plan."""

    steps: int
    app: str
    log: Path | None = None
    cancelled: bool = False


def apply(machine: Machine, path: Path, desired: DesiredState, *, options: ApplyOptions,
          confirm: Callable[[Plan], bool], report: Report, local: bool = False,
          base_dir: Path | None = None, places: Sequence[tuple[int, int]] = ()) -> Applied:
    """`lpam apply [-f FILE]`: the plan is reported (`Planned`) and `confirm`ed before it
    runs; nothing changes when it is declined. `local`: use no network, resolving refs as
    the last fetch (or an unpacked bundle) left them; refused if anything is not local.
    `places`: each desired app's (line, column) in `path`, as `plan` takes them."""
    from reconciler.core.planning.holds import desired_ref
    from reconciler.core.planning.plan import unknown_values
    from reconciler.engine.execution.lock import apply_lock
    from reconciler.engine.observe.targets import Fetch

    with apply_lock(machine.layout, timeout=options.lock_wait()) as lock:
        if options.release:
            _release(machine, report)
        fetch = Fetch.OFFLINE if local else Fetch.CHECKOUT
        store, made = prepare(machine, path, desired, fetch=fetch, report=report,
                              places=places)
        report(Planned(made))
        missing = unknown_values(made) if local else []
        if missing:
            raise LpamError(f"with no network, these are not known: {', '.join(missing)}",
                            hint="fetch them first (`lpam sync --fetch-only` where there is "
                            "network, or a bundle); nothing was changed")
        if not made.steps and not finishes_rollback(made):
            _settle(machine, made, desired_ref(desired, str(path)), by=options.by)
            return Applied(0, standing(machine))
        if not confirm(made):
            return Applied(0, standing(machine), cancelled=True)
        base = base_dir if base_dir is not None else path.resolve().parent
        return execute_plan(machine, store, made, lock, options=options, report=report,
                            gate=machine.gate_for(desired, base),
                            listener=machine.listener_for(desired, base),
                            desired=desired_ref(desired, str(path)))


def apply_file(machine: Machine, path: Path, *, options: ApplyOptions,
               confirm: Callable[[Plan], bool], report: Report) -> Applied:
    """`lpam apply [-f FILE]`: the desired state at `path` read — refused before the lock,
    while the network helper starts — then applied as `apply` does."""
    from reconciler.core.documents import load_desired_document

    machine.warm_network()
    if options.release and path == machine.layout.desired_state:
        fleet = _end_override(machine, options, report)
        if fleet is not None:  # the car follows its fleet's file again, at once
            return apply(machine, fleet.label, fleet.desired, options=options,
                         confirm=confirm, report=report, base_dir=fleet.base_dir,
                         places=fleet.places)
    document = load_desired_document(path)
    return apply(machine, path, document.desired, options=options, confirm=confirm,
                 report=report, places=document.places)


def _end_override(machine: Machine, options: ApplyOptions, report: Report) -> Followed | None:
    """`lpam apply --release` on a car under a local override (workflow/override.py):
    the override ends, and the desired state to apply is the fleet's file at the revision
    the agent applied (None: no override, or the agent never applied one)."""
    from reconciler.engine.execution.lock import apply_lock
    from reconciler.workflow import override
    from reconciler.workflow.followed import applied_desired

    with apply_lock(machine.layout, timeout=options.lock_wait()):
        if override.end(machine, report) is None:
            return None
    return applied_desired(machine)


def _settle(machine: Machine, made: Plan, desired: DesiredRef, *,
            by: Actor | None) -> None:
    """Nothing to do: a deferred, interrupted or cut-off apply before this one no longer
    applies (engine/execution/recovery.py `settled`), and its journal ends with it."""
    import uuid

    from reconciler.engine.execution.recovery import settled
    from reconciler.engine.records.journal import Journal
    from reconciler.engine.records.state import read_record, write_record

    now = machine.clock()
    record = settled(read_record(machine.layout), now=now.isoformat(timespec="seconds"),
                     desired=desired, by=by)
    if record is None:
        return
    try:
        write_record(machine.layout, record)
    except OSError as exc:  # the machine matches; only the old words stay (a full disk)
        raise StateWriteError(f"cannot write the state record: {exc.strerror or exc}",
                              path=machine.layout.state_record) from None
    journal = Journal(machine.layout, apply_id=str(uuid.uuid4()), plan=made.fingerprint)
    try:  # advisory, as ever: the record is what lpam trusts
        journal.open(now)
        journal.close(now)
    except (OSError, LpamError):
        pass


def finishes_rollback(made: Plan) -> bool:
    """The plan finishes a rollback a fault cut off: run even with no step left, so that
    the failure is recorded (workflow/planning.py)."""
    return any(c.address == "rollback" for c in made.changes)


def apply_plan_file(machine: Machine, path: Path, *, options: ApplyOptions,
                    report: Report) -> Applied:
    """`lpam apply PLANFILE`: the saved plan is read, validated step by step and its seal
    checked before anything waits for the lock (a tampered plan is refused at once, at its
    line and column), then applied as `apply_saved` says."""
    from reconciler.core.documents import load_plan

    saved = load_plan(path)
    return apply_saved(machine, saved, str(path), options=options, report=report)


def apply_saved(machine: Machine, saved: Plan, source: str, *, options: ApplyOptions,
                report: Report) -> Applied:
    """`lpam apply PLANFILE`: refused when it is stale, edited, offline or inexact. A plan
    holds no gates: it obeys those of the desired state in force (workflow/gates.py), read
    here before the lock, so that no caller can run one ungated by forgetting them."""
    from reconciler.core.planning.plan import check_plan
    from reconciler.engine.execution.lock import apply_lock
    from reconciler.engine.records.state import read_record
    from reconciler.workflow.gates import governing

    gates = governing(machine, None)
    with apply_lock(machine.layout, timeout=options.lock_wait()) as lock:
        record = read_record(machine.layout)
        check_plan(saved, lineage=record.lineage, serial=record.serial, source=source)
        return execute_plan(machine, machine.store(), saved, lock, options=options,
                            report=report, gate=gates.gate, listener=gates.listener)


def execute_plan(machine: Machine, store: GitStore, made: Plan, lock: Lock, *,
                 options: ApplyOptions, report: Report, gate: Gate | None,
                 listener: Listener | None, desired: DesiredRef | None = None) -> Applied:
    from reconciler.engine.execution.executor import execute

    ctx, log = machine.context(store, lock, command="apply",
                               script_timeout=options.script_timeout, report=report,
                               gate=gate, gate_wait=options.wait, listener=listener,
                               resume=options.resume, desired=desired,
                               retry_after=options.retry_after, by=options.by)
    execute(made, ctx, progress=lambda text: report(Progress(text)),
            keep=options.keep_generations)
    return Applied(len(made.steps), standing(machine, ctx.record.apps), log)


def installed_apps(record: StateRecord, name: str | None, nothing: str) -> list[AppRecord]:
    """The installed apps a command works on: the one named, else all. With no app
    installed, or a name that is not installed, it is refused (`nothing`: what the command
    then cannot do), naming the installed apps."""
    if not record.apps:
        raise LpamError(f"no app is installed: {nothing}", hint="install one with `lpam apply`")
    if name is None:
        return list(record.apps)
    found = record.installed(name)
    if found is None:
        raise LpamError(f"no installed app is named {name!r}: {nothing}",
                        hint=f"installed: {', '.join(a.name for a in record.apps)}")
    return [found]


def standing(machine: Machine, apps: Sequence[AppRecord] | None = None) -> str:
    """The installed apps as they stand (the record's, unless given), each unit asked of
    the service manager."""
    from reconciler.engine.records.state import read_record

    current = read_record(machine.layout).apps if apps is None else apps
    if not current:  # a sentence of its own: "No app enabled; no app." said nothing
        return "no app is installed"
    return "; ".join(_standing(machine, app) for app in current)


def _standing(machine: Machine, app: AppRecord) -> str:
    """The app in the status report's words (reconciler/report/build.py), with its unit as
    its manager answers: an app adopted in place ran no script, so nothing here says what
    scripts reported."""
    from reconciler.report.build import said

    state = None if app.service is None else machine.services.state(app.service)
    unit = "" if state is None else f" ({state.describe()})"
    return f"{app.name} {said(app, state)}{unit}"


def _release(machine: Machine, report: Report) -> None:
    from reconciler.engine.records.state import read_record, write_record

    record = read_record(machine.layout)
    hold = record.hold
    if hold is not None:
        record = write_record(machine.layout, record.model_copy(update={"hold": None}))
        report(Progress(f"Released the hold on generation {hold.name}."))
    for app in record.apps:
        if app.held:
            record = write_record(machine.layout, record.with_app(
                app.name, app.model_copy(update={"held": False, "held_by": None})))
            report(Progress(f"Released the operator's stop of {app.name}."))
