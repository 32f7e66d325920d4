"""The builders of one app's steps, and the record as the service manager sees it.

core/planning/decision.py decides, for each app, what happens and why; the steps it
chooses are built here, so that a plan, an operator's command and the rollback of a
failed cutover name their steps alike: a step's id is its kind and the generation it
works on, and a step carries everything the executor needs to run it (the generation as
recorded for an installed app, as wanted for a new one). Strays (apps on disk that no
record knows) are stopped and uninstalled with their own scripts; LPAM's app that is the
desired one as it is, is adopted in place.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from reconciler.base.unit import UnitState
from reconciler.core.planning.model import UNKNOWN, AppTarget, GenerationKey, HealthTarget
from schemas.generation import AppGeneration, GenerationFields, StrayGeneration
from schemas.operator import OperatorAction
from schemas.plan import (
    AdoptStep,
    ConfigureStep,
    HealthCheck,
    InstallStep,
    Phase,
    StageStep,
    StartStep,
    Step,
    StepKind,
    StopStep,
    UninstallStep,
    VerifyStep,
)
from schemas.record import AppRecord, StateRecord, Stray

SAME_GENERATION: dict[str, tuple[StepKind, ...]] = {  # the installed generation wanted
    "running": (),
    "installed": (StepKind.START,),
    "starting": (StepKind.START,),
    "installing": (StepKind.INSTALL, StepKind.START),
    "stopping": (StepKind.STOP, StepKind.START),
    "uninstalling": (StepKind.INSTALL, StepKind.START),
}


_ON_GENERATION: dict[StepKind, type[StageStep | InstallStep | ConfigureStep | StartStep]] = {
    StepKind.STAGE: StageStep, StepKind.INSTALL: InstallStep,
    StepKind.CONFIGURE: ConfigureStep, StepKind.START: StartStep}
_LEAVING: dict[StepKind, type[StopStep | UninstallStep]] = {
    StepKind.STOP: StopStep, StepKind.UNINSTALL: UninstallStep}


def step_id(kind: StepKind, target: str) -> str:
    """A step's id: its kind and what it works on (`install:alpha@1a2b…`)."""
    return f"{kind.value}:{target}"


def on(kind: StepKind, target: str, app: AppGeneration, *, good: bool = False,
       phase: Phase = Phase.CUTOVER) -> Step:
    """A step of `kind` on the generation `app`: a stage, install, configure or start
    (`good`: whether it counts as good once the step ends), or a stop or an uninstall."""
    ident = step_id(kind, target)
    if kind in _LEAVING:
        return _LEAVING[kind](id=ident, phase=phase, app=app)
    return _ON_GENERATION[kind](id=ident, phase=phase, app=app, good=good)


def same_generation(old: AppRecord, new: AppTarget,
                    generations: frozenset[GenerationKey]) -> bool:
    """True when `new` runs the installed generation (same folder content, same way of
    running, folder on disk), whatever its parameters."""
    if (old.name, old.repository) != (new.name, new.repository):
        return False
    if (old.command, old.launch) != (_list(new.command), new.launch):
        return False
    same = new.tree == old.tree if new.tree is not None else new.commit == old.commit
    return same and GenerationKey.of(old.name, old.generation) in generations


def adopted_steps(stray: Stray, new: AppTarget, generations: frozenset[GenerationKey], *,
                  start: bool, verify: bool) -> list[Step]:
    """Take over LPAM's app in place (engine/observe/adoption.py found it to be `new` as
    it is): its generation staged from git (same content as LPAM's folder), then recorded
    as installed — running if its unit runs — with no script; started only if it was not
    running."""
    assert stray.folder is not None, "engine/observe/adoption.py adopts only an app LPAM installed"
    gen = new.generation or UNKNOWN
    target = f"{new.name}@{gen}"
    steps: list[Step] = []
    if GenerationKey.of(new.name, gen) not in generations:
        steps.append(on(StepKind.STAGE, target, generation_of(new, gen), good=new.proven,
                        phase=Phase.PREPARE))
    steps.append(AdoptStep(id=step_id(StepKind.ADOPT, target), phase=Phase.CUTOVER,
                           app=generation_of(new, gen), folder=stray.folder,
                           running=not stray.stopped))
    if stray.stopped and start:
        steps += started(new, gen, target, verify=verify)
    return steps


def started(new: AppTarget, gen: str, target: str, *, verify: bool) -> list[Step]:
    """START, then VERIFY when there is something to check. The app is good once started
    only when it proved good before or an apply has nothing to check; else its verify,
    run to its end, makes it good."""
    checks = verify and _checks(new.health)
    good = new.proven or (verify and not checks)
    steps = [on(StepKind.START, target, generation_of(new, gen), good=good)]
    if checks:
        steps.append(verified(new, gen, target))
    return steps


def verified(new: AppTarget, gen: str, target: str) -> VerifyStep:
    health = new.health
    check = HealthCheck(settle_seconds=health.settle_seconds,
                        timeout_seconds=health.timeout_seconds, command=_list(health.command),
                        can_ids=list(health.can_ids), can_within_seconds=health.can_within)
    return VerifyStep(id=step_id(StepKind.VERIFY, target), phase=Phase.CUTOVER,
                      app=generation_of(new, gen), health=check)


def _checks(health: HealthTarget) -> bool:
    """Whether a health check has anything to check (`settle_seconds: 0` turns it off)."""
    return health.settle_seconds > 0 or health.command is not None or bool(health.can_ids)


def stray_steps(strays: Sequence[Stray]) -> list[Step]:
    """Each stray stopped (unless it is known to be stopped) and uninstalled with its own
    scripts."""
    steps: list[Step] = []
    for stray in strays:
        found = "taken over from LPAM" if stray.folder is not None else "found on disk"
        target = f"{stray.name}@{stray.generation} ({found})"
        found_as = StrayGeneration(name=stray.name, generation=stray.generation,
                                   params=dict(stray.params))
        kinds = (StepKind.UNINSTALL,) if stray.stopped else (StepKind.STOP, StepKind.UNINSTALL)
        steps += [_LEAVING[k](id=step_id(k, target), phase=Phase.CUTOVER, stray=found_as)
                  for k in kinds]
    return steps


def _list(value: tuple[str, ...] | list[str] | None) -> list[str] | None:
    return None if value is None else list(value)


def recorded(app: AppRecord) -> AppGeneration:
    """The installed app as a step names it: everything a reinstall needs to run it the
    way it ran (a scriptless app's unit must not come back as a script app). Its
    generation is the recorded one: an older lpam derived ids differently."""
    shared = {*GenerationFields.model_fields, "commit", "path", "tree"}
    return AppGeneration(**app.model_dump(include=shared))


def generation_of(new: AppTarget, gen: str) -> AppGeneration:
    """The wanted app as a step names it, with its runtime (environment, ROS build)."""
    deps = new.deps
    ros = bool(deps.ros) and deps.workspace is not None
    return AppGeneration(
        name=new.name, generation=gen, repository=new.repository, commit=new.commit,
        path=new.path, tree=new.tree, params=dict(new.params), service=new.service,
        command=_list(new.command), launch=new.launch, user=new.user, pip=list(deps.pip),
        ros={r.name: r.commit or UNKNOWN for r in deps.ros} if ros else {},
        ros_build=(deps.ros_build or UNKNOWN) if ros else None,
        ros_workspace=deps.workspace.path if ros and deps.workspace else None,
        ros_user=deps.workspace.user if ros and deps.workspace else None,
        resources=sorted(new.resources), data=list(new.data))


def target_of(app: AppRecord) -> AppTarget:
    """The recorded app as a target again: what a rollback returns to."""
    return AppTarget(name=app.name, repository=app.repository, commit=app.commit,
                     path=app.path, tree=app.tree, params=dict(app.params),
                     service=app.service,
                     command=tuple(app.command) if app.command is not None else None,
                     launch=app.launch, user=app.user, health=HealthTarget(settle_seconds=0),
                     resources=app.claims, data=tuple(app.data), proven=app.good)


def refreshed(record: StateRecord, lives: Mapping[str, UnitState],
              stray_live: Mapping[str, UnitState] | None = None) -> StateRecord:
    """The record as the service manager sees each app now (Terraform's refresh: the
    record stays the prior state, this is the one planned from). An app recorded as
    running whose unit the manager knows and reports not active has stopped behind lpam's
    back (a crash, a reboot, someone's `systemctl stop`): it is planned as installed, so it
    is started. One recorded as installed whose unit is active may hold the bus: planned
    as running, so it is stopped before anything else is installed. `lives`: each
    installed app's unit, by name."""
    record = strays_refreshed(record, stray_live or {})
    for app in record.apps:
        record = record.with_app(app.name, refreshed_app(app, lives.get(app.name)))
    return record


def refreshed_app(app: AppRecord, live: UnitState | None) -> AppRecord:
    if live is None or not live.known:
        return app
    if live.running and not live.supervised and app.status in ("running", "installed"):
        # its manager died and left it running: stopped (the manager's successor finds
        # and ends what it ran), then started again under it unless an operator stopped it
        status = "stopping"
    elif app.status == "running" and not live.running:
        status = "installed"
    elif app.status == "installed" and live.running:
        status = "running"  # started behind lpam's back, or a stop that did not stop it
    else:
        return app
    return app.model_copy(update={"status": status})


def operated(app: AppRecord, action: OperatorAction) -> AppRecord:
    """The app as an operator's command plans it: a stop keeps it as it is (its hold, once
    written, keeps it stopped); a start ends the hold; a restart of an app that may run
    first finishes a stop."""
    if action == OperatorAction.STOP:
        return app
    if action == OperatorAction.RESTART and app.status in ("running", "starting"):
        return app.model_copy(update={"status": "stopping", "held": False,
                                        "held_by": None})
    return app.model_copy(update={"held": False, "held_by": None})


def strays_refreshed(record: StateRecord, live: Mapping[str, UnitState]) -> StateRecord:
    """An app LPAM installed counts as running only if its unit is active: one whose unit
    its manager reports inactive needs no stop, only its uninstall."""
    strays = [s.model_copy(update={"stopped": True})
              if s.name in live and live[s.name].known and not live[s.name].running else s
              for s in record.strays]
    return record.model_copy(update={"strays": strays}) if strays != record.strays else record


_NEXT = {
    "running": "runs",
    "installed": "is installed, not running: the next apply starts it",
    "starting": "was being started: the next apply starts it again",
    "installing": "was being installed: the next apply installs it again and starts it",
    "stopping": "was being stopped: the next apply stops it, then goes on",
    "uninstalling": "was being uninstalled: the next apply installs it again and goes on",
}


def resume_text(record: StateRecord) -> str:
    """What the record shows and what the next apply of the same desired state does from
    it, in a sentence or two: said when lpam had to stop where it stood."""
    cutover = record.cutover
    back = ", ".join(a.name for a in cutover.previous) if cutover is not None else ""
    back_to = f"it returns to {back}" if back else "it removes it again"
    if not record.apps:
        text = "The record shows no app installed: the next apply installs the desired one."
    else:
        text = " ".join(_app_resume(app, back_to) for app in record.apps)
    if cutover is not None and cutover.rollback is not None:
        text += f" A rollback to {back or 'no app'} was under way: the next apply finishes " \
            "it first."
    return text


def _app_resume(app: AppRecord, back_to: str) -> str:
    text = f"The record shows {app.name} ({app.generation}): it {_NEXT[app.status]}."
    if app.held:
        text += " An operator stopped it: it stays stopped."
    elif not app.good:
        text += (" It has not passed its health check yet: the next apply checks it for "
                 f"a whole settle window, and if it fails, {back_to}.")
    return text
