"""The app's lifecycle steps: from what the record says to the app that is wanted.

One pure function serves the plan *and* the rollback of a failed cutover, so both obey the
same two rules of the vehicle:
- nothing is installed while another app (or a stray found on disk) may still hold the
  CAN hardware: every other app is stopped (when it may be active) and uninstalled first;
- a script that was cut off (the status still says `starting`, `stopping`, …) is finished
  or redone, never assumed to have worked.

Same generation wanted as recorded, by status:

| status        | steps            | why                                                   |
|---------------|------------------|-------------------------------------------------------|
| running       | —                |                                                       |
| installed     | start            |                                                       |
| starting      | start            | start.sh was cut off or failed                        |
| installing    | install, start   | install.sh was cut off or failed                      |
| stopping      | stop, start      | finish the stop before starting again                 |
| uninstalling  | install, start   | uninstall.sh failed: install.sh puts the app back     |

Otherwise the recorded app is stopped (if it may be active) and uninstalled, then the new
generation is staged (during preparation), installed and started.
"""

from __future__ import annotations

from reconciler.planning.model import UNKNOWN, AppTarget, GenerationKey
from schemas.plan import Phase, Step, StepKind
from schemas.record import ACTIVE, AppRecord, StateRecord

_SAME_GENERATION: dict[str, tuple[StepKind, ...]] = {
    "running": (),
    "installed": (StepKind.START,),
    "starting": (StepKind.START,),
    "installing": (StepKind.INSTALL, StepKind.START),
    "stopping": (StepKind.STOP, StepKind.START),
    "uninstalling": (StepKind.INSTALL, StepKind.START),
}


def step(kind: StepKind, phase: Phase, target: str,
         **args: str | dict[str, str] | None) -> Step:
    return Step(id=f"{kind.value}:{target}", kind=kind, phase=phase, args=args)


def keeps(old: AppRecord, new: AppTarget, generations: frozenset[GenerationKey]) -> bool:
    """True when `new` is the generation already installed (and its folder is on disk)."""
    if (old.name, old.repository, old.params) != (new.name, new.repository, new.params):
        return False
    same = new.tree == old.tree if new.tree is not None else new.commit == old.commit
    return same and GenerationKey.of(old.name, old.generation) in generations


def app_steps(
    record: StateRecord, new: AppTarget | None, generations: frozenset[GenerationKey], *,
    start: bool = True,
) -> list[Step]:
    """The steps that take the record's app (and strays) to `new`, started if `start`."""
    old = record.app
    steps = _stray_steps(record)
    if new is not None and old is not None and keeps(old, new, generations):
        kinds = _SAME_GENERATION[old.status]
        if not start:
            kinds = tuple(k for k in kinds if k is not StepKind.START)
            if old.status in ("starting", "running"):
                kinds = (StepKind.STOP,)
        target = f"{old.name}@{old.generation}"
        return steps + [step(k, Phase.CUTOVER, target, **_recorded(old)) for k in kinds]
    gen = (new.generation or UNKNOWN) if new is not None else None
    if new is not None and gen is not None and GenerationKey.of(new.name, gen) not in generations:
        steps.insert(0, step(StepKind.STAGE, Phase.PREPARE, f"{new.name}@{gen}",
                             **_wanted(new, gen)))
    if old is not None:
        target = f"{old.name}@{old.generation}"
        if old.status in ACTIVE:
            steps.append(step(StepKind.STOP, Phase.CUTOVER, target, **_recorded(old)))
        steps.append(step(StepKind.UNINSTALL, Phase.CUTOVER, target, **_recorded(old)))
    if new is not None and gen is not None:
        target = f"{new.name}@{gen}"
        steps.append(step(StepKind.INSTALL, Phase.CUTOVER, target, **_wanted(new, gen)))
        if start:
            steps.append(step(StepKind.START, Phase.CUTOVER, target, **_wanted(new, gen)))
    return steps


def _stray_steps(record: StateRecord) -> list[Step]:
    steps = []
    for stray in record.strays:
        target = f"{stray.name}@{stray.generation} (found on disk)"
        args: dict[str, str | dict[str, str] | None] = {
            "app": stray.name, "generation": stray.generation, "params": dict(stray.params),
            "stray": "yes",
        }
        if not stray.stopped:
            steps.append(step(StepKind.STOP, Phase.CUTOVER, target, **args))
        steps.append(step(StepKind.UNINSTALL, Phase.CUTOVER, target, **args))
    return steps


def _recorded(app: AppRecord) -> dict[str, str | dict[str, str] | None]:
    return {"app": app.name, "generation": app.generation, "repository": app.repository,
            "commit": app.commit, "path": app.path, "tree": app.tree,
            "params": dict(app.params)}


def _wanted(new: AppTarget, gen: str) -> dict[str, str | dict[str, str] | None]:
    return {"app": new.name, "generation": gen, "repository": new.repository,
            "commit": new.commit, "path": new.path, "tree": new.tree,
            "params": dict(new.params)}


def target_of(app: AppRecord) -> AppTarget:
    """The recorded app as a target again: what a rollback returns to."""
    return AppTarget(name=app.name, repository=app.repository, commit=app.commit,
                     path=app.path, tree=app.tree, params=dict(app.params))
