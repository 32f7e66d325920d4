"""One decision per app: what happens to it, why, and by which steps — made once.

For each app (the installed app of a name, the desired app of that name, or both) `decide`
chooses the action, a typed reason and the steps in one branch, so the plan's change text
(`Decision.change`, rendered from the reason's facts) and its steps cannot disagree: a
reason is a closed set of kinds, each a frozen value holding the facts that chose it, and
its text is derived from those facts alone.

The rules of the steps (core/planning/lifecycle.py builds them): nothing is installed
while another app that claims what it claims may still hold it (core/planning/ensemble.py
orders apps); a script that was cut off (the status still says `starting`, `stopping`, …)
is finished or redone, never assumed to have worked:

| status (as the service manager sees it) | steps          | why                          |
|-----------------------------------------|----------------|------------------------------|
| running                                 | —              |                              |
| installed                               | start          |                              |
| starting                                | start          | start.sh cut off or failed   |
| installing                              | install, start | install.sh cut off or failed |
| stopping                                | stop, start    | finish the stop first        |
| uninstalling                            | install, start | install.sh puts the app back |

An app an operator stopped (`held`) is never started; one that may still run is stopped.
An app that has not proved itself (`good` is false) is checked again for a whole settle
window after whatever finishes it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, Union

from reconciler.base.unit import UnitState
from reconciler.core.planning.lifecycle import (
    SAME_GENERATION,
    adopted_steps,
    generation_of,
    on,
    recorded,
    refreshed_app,
    same_generation,
    started,
    verified,
)
from reconciler.core.planning.model import (
    LIFECYCLE_SCRIPTS,
    UNKNOWN,
    AppTarget,
    GenerationKey,
    short,
)
from schemas.plan import Action, Change, Phase, Step, StepKind
from schemas.record import ACTIVE, AppRecord, Stray

Fields = dict[str, Union[str, bool, dict[str, str], None]]


@dataclass(frozen=True)
class Install:
    """A desired app that is not installed."""

    action: ClassVar[Action] = Action.CREATE
    app: str
    repository: str
    commit: str | None

    def said(self) -> str:
        return f"install {self.app} from {self.repository} at {short(self.commit)}"


@dataclass(frozen=True)
class Adopt:
    """An app LPAM installed that is the desired app as it is (engine/observe/adoption.py);
    `starts`: it was not running, and this plan starts it."""

    action: ClassVar[Action] = Action.CREATE
    app: str
    stray: str
    repository: str
    commit: str | None
    starts: bool = False

    def said(self) -> str:
        then = ("nothing is reinstalled; it was not running: started" if self.starts
                else "no script runs and it is not restarted")
        return (f"{self.app}, installed by LPAM as {self.stray}, is the desired app as it is "
                f"(same files as {self.repository} at {short(self.commit)}): adopted in place "
                f"— {then}")


@dataclass(frozen=True)
class Remove:
    """An installed app no longer desired; `heirs`: arriving apps that claim something it
    claims (`claims`: what they share); `stops`: it may run, so it is stopped first."""

    action: ClassVar[Action] = Action.DELETE
    app: str
    heirs: tuple[str, ...] = ()
    claims: tuple[str, ...] = ()
    stops: bool = True

    def said(self) -> str:
        text = f"app {self.app} is no longer desired: {_leaves(self.stops)}"
        if self.heirs:
            one = len(self.heirs) == 1
            text += (f" before {', '.join(self.heirs)}, which {'claims' if one else 'claim'} "
                     f"what it claims ({', '.join(self.claims)}), "
                     f"{'is' if one else 'are'} installed")
        return text


@dataclass(frozen=True)
class Moved:
    """The desired app of this name comes from another repository."""

    action: ClassVar[Action] = Action.REPLACE
    app: str
    was: str
    now: str
    stops: bool = True

    def said(self) -> str:
        return (f"{self.app} now comes from {self.now} (installed from {self.was}): the "
                f"installed one is {_leaves(self.stops)} before the new one is installed")


@dataclass(frozen=True)
class KnownAfterFetch:
    """Offline, with repositories not fetched yet: which one offers the app is unknown."""

    action: ClassVar[Action] = Action.UPDATE
    app: str

    def said(self) -> str:
        return (f"{self.app}: which repository offers it, and whether its folder changed, are "
                "known after fetch")


@dataclass(frozen=True)
class NewGeneration:
    """Another generation is wanted: a new folder (`folder`: the trees, None when the
    commits are compared until a fetch), or the same folder run differently."""

    action: ClassVar[Action] = Action.UPDATE
    app: str
    folder: tuple[str, str] | None
    new_folder: bool
    params_changed: bool
    stops: bool = True

    def said(self) -> str:
        if not self.new_folder:
            what = ["runs differently"]
        elif self.folder is None:
            what = ["new version (folder compared after fetch)"]
        else:
            what = [f"new version (folder {self.folder[0][:12]} → {self.folder[1][:12]})"]
        if self.params_changed:
            what.append("parameters changed")
        return (f"{self.app}: {', '.join(what)}; the old generation is {_leaves(self.stops)} "
                "before the new one is installed")


@dataclass(frozen=True)
class FolderMissing:
    """The installed generation is the wanted one, but its folder is gone from disk."""

    action: ClassVar[Action] = Action.UPDATE
    app: str
    stops: bool = True

    def said(self) -> str:
        stopped = "stopped, " if self.stops else ""
        return (f"{self.app}: its installed folder is missing from disk: {stopped}copied out "
                "of git again and reinstalled")


@dataclass(frozen=True)
class Reconfigure:
    """New parameters (`keys`; none: a new user) for the installed generation; `stops`: it
    may run, so it is stopped first; `scripts`: the lifecycle scripts the app has (none:
    a scriptless app, whose unit lpam rewrites with the new values)."""

    action: ClassVar[Action] = Action.UPDATE
    app: str
    keys: tuple[str, ...]
    reinstall: bool  # its install was cut off: it runs again first
    restart: bool
    stops: bool = True
    scripts: frozenset[str] = LIFECYCLE_SCRIPTS

    def said(self) -> str:
        what = f"parameters changed ({', '.join(self.keys)})" if self.keys else "user changed"
        if self.restart:
            then = f"{'restarted' if self.stops else 'started'} with the new values"
        else:
            then = f"{'stopped and ' if self.stops else ''}recorded, not started"
        has = "install.sh" in self.scripts
        if self.reinstall:
            script = f"its install{' script' if has else ''}, cut off before, runs again first"
        else:
            script = "no install script runs" if has else "nothing is reinstalled"
        return f"{self.app} {what}: {then}; {script}, no new generation"


@dataclass(frozen=True)
class Held:
    """The app is not to be started: an operator's stop holds it (`operator`: `lpam
    stop`), or the command starts nothing (an operator's stop of the set, a rollback to
    a stopped app). `may_run`: it may still run (its stop was cut off, or it runs):
    stopped; `status` installing or uninstalling: its script was cut off: installed
    again, and it stays stopped."""

    app: str
    status: str
    may_run: bool = False
    operator: bool = True
    scripts: frozenset[str] = LIFECYCLE_SCRIPTS

    @property
    def reinstall(self) -> bool:
        return self.status in ("installing", "uninstalling")

    @property
    def action(self) -> Action:
        return Action.UPDATE if self.may_run or self.reinstall else Action.NOOP

    def said(self) -> str:
        asked = ", as an operator asked (`lpam stop`)" if self.operator else ""
        if self.reinstall:
            return (f"{self.app} {_finished(self.status, self.scripts).split(':')[0]}: "
                    f"installed again; it stays stopped{asked}")
        if self.may_run and self.operator:
            return (f"{self.app} was stopped by an operator (`lpam stop`), but that stop did "
                    "not finish and it may still run: stopped")
        if self.may_run:
            return f"{self.app} may run: stopped, and not started again"
        if self.operator:
            return (f"{self.app} was stopped by an operator (`lpam stop`) and stays stopped "
                    "until `lpam start` or a change of the desired state")
        return f"{self.app} is not running, and is not started"


@dataclass(frozen=True)
class Unsupervised:
    """It runs, but its service manager died: stopped, then started under a new one."""

    action: ClassVar[Action] = Action.UPDATE
    app: str
    unit: str

    def said(self) -> str:
        return (f"{self.app} runs without its service manager ({self.unit}): stopped, then "
                "started again under a new one (never a second copy beside it)")


@dataclass(frozen=True)
class NotRunning:
    """Recorded as running, its unit is not active: started."""

    action: ClassVar[Action] = Action.UPDATE
    app: str
    unit: str
    unproven: bool = False

    def said(self) -> str:
        return f"{self.app} is not running ({self.unit}): start" + _unproven(self.unproven)


@dataclass(frozen=True)
class StartedOutside:
    """Recorded as installed, its unit is active: lpam did not start it."""

    action: ClassVar[Action] = Action.NOOP
    app: str
    unit: str

    def said(self) -> str:
        return f"{self.app} runs ({self.unit}), though lpam did not start it"


@dataclass(frozen=True)
class Running:
    """Installed and running as wanted; `moved_to`: its repository's new commit, which
    leaves its folder as it is; `unproven`: its health is checked again."""

    app: str
    moved_to: str | None = None
    unproven: bool = False

    @property
    def action(self) -> Action:
        return Action.UPDATE if self.unproven else Action.NOOP

    def said(self) -> str:
        if self.unproven:
            return f"{self.app} is running" + _unproven(True)
        moved = "" if self.moved_to is None else f"; repository now at {short(self.moved_to)}"
        return f"{self.app} installed and running, app folder unchanged{moved}"


_FINISHED = {
    "installed": "is installed but not running: started",
    "starting": "was being started when the last apply stopped ({}): started again",
    "installing": "was being installed when the last apply stopped ({}): installed again "
    "and started",
    "stopping": "was being stopped when the last apply stopped: stopped, then started again",
    "uninstalling": "was being uninstalled when the last apply stopped: installed again and "
    "started",
}
_CUT = {"starting": "start", "installing": "install"}


def _finished(status: str, scripts: frozenset[str]) -> str:
    """What finishing a cut-off lifecycle does; a script is named only when the app has it
    (a scriptless app's unit lpam starts itself; a folder may lack start.sh)."""
    cut = _CUT.get(status, "")
    script = f"{cut}.sh"
    what = f"{script} cut off or failed" if script in scripts else f"its {cut} cut off or failed"
    return _FINISHED[status].format(what)


@dataclass(frozen=True)
class Finish:
    """A script was cut off, or the app is installed and not running: finished or redone;
    `scripts`: the lifecycle scripts the app has (none: a scriptless app)."""

    action: ClassVar[Action] = Action.UPDATE
    app: str
    status: str
    unproven: bool = False
    scripts: frozenset[str] = LIFECYCLE_SCRIPTS

    def said(self) -> str:
        return f"{self.app} {_finished(self.status, self.scripts)}" + _unproven(self.unproven)


def _leaves(stops: bool) -> str:
    """How an installed generation leaves: stopped only when it may run."""
    return "stopped and uninstalled" if stops else "uninstalled (it is not running)"


def _unproven(unproven: bool) -> str:
    # the record's `good` is cleared by an install and by new parameters alike
    return ("; it has not passed its health check since it was installed or its parameters "
            "last changed (the check did not run to its end): checked again for a whole "
            "settle window" if unproven else "")


Reason = Union[Install, Adopt, Remove, Moved, KnownAfterFetch, NewGeneration, FolderMissing,
               Reconfigure, Held, Unsupervised, NotRunning, StartedOutside, Running, Finish]
"""Why an app's plan is what it is: every kind there is, each with the facts that chose it."""


@dataclass(frozen=True)
class Decision:
    """One app's plan: the reason and the steps chosen together, and the app before and
    after as the plan shows them."""

    app: str
    reason: Reason
    steps: tuple[Step, ...]
    before: Fields | None
    after: Fields | None

    @property
    def action(self) -> Action:
        return self.reason.action

    def change(self) -> Change:
        """The plan's change for this app, its text derived from the reason."""
        reason = self.reason
        warnings = []
        if isinstance(reason, Held) and reason.action is Action.NOOP:
            warnings.append(reason.said())
        elif isinstance(reason, StartedOutside):
            warnings.append(f"{reason.app} was started outside lpam")
        return Change(address=f"app.{self.app}", action=self.action, reason=reason.said(),
                      before=self.before, after=self.after, warnings=warnings)


def decide(old: AppRecord | None, new: AppTarget | None,
           generations: frozenset[GenerationKey], live: UnitState | None = None, *,
           start: bool = True, verify: bool = True, adopted: Stray | None = None,
           heirs: Sequence[AppTarget] = ()) -> Decision:
    """The decision for one app: `old` the installed app of its name as recorded, `live`
    its unit now, `new` the app wanted. Started if `start` (its health checked if
    `verify`); `adopted`: the app LPAM installed that `new` is, as it is; `heirs`: the
    arriving apps that claim what a leaving `old` claims."""
    before = None if old is None else _fields(old.name, old.repository, old.commit,
                                              old.params, old.status)
    after = None if new is None else _fields(new.name, new.repository, new.commit,
                                             new.params, None)
    reason, steps = _chosen(old, new, generations, live, start=start, verify=verify,
                            adopted=adopted, heirs=heirs)
    name = new.name if new is not None else old.name if old is not None else ""
    return Decision(name, reason, tuple(steps), before, after)


def _chosen(old: AppRecord | None, new: AppTarget | None,
            generations: frozenset[GenerationKey], live: UnitState | None, *, start: bool,
            verify: bool, adopted: Stray | None,
            heirs: Sequence[AppTarget]) -> tuple[Reason, list[Step]]:
    # what runs is what the service manager says (Terraform's refresh): an app recorded
    # as installed whose unit is active is stopped before it is uninstalled
    seen = None if old is None else refreshed_app(old, live)
    if new is None:
        assert old is not None and seen is not None, "an app is installed, desired, or both"
        heirs = [h for h in heirs if h.resources & old.claims]  # only they wait for it
        shared = tuple(sorted(old.claims & frozenset().union(*(h.resources for h in heirs))))
        reason = Remove(old.name, tuple(h.name for h in heirs), shared, _stops(seen))
        return reason, _replaced(seen, None, generations, start=start, verify=verify)
    if old is None or seen is None:
        if adopted is not None:
            return (Adopt(new.name, adopted.name, new.repository, new.commit,
                          starts=adopted.stopped and start),
                    adopted_steps(adopted, new, generations, start=start, verify=verify))
        return (Install(new.name, new.repository, new.commit),
                _replaced(None, new, generations, start=start, verify=verify))
    if same_generation(old, new, generations):
        return _same(old, seen, new, live, start=start, verify=verify)
    return _other(old, new, _stops(seen)), _replaced(seen, new, generations, start=start,
                                                     verify=verify)


def _stops(seen: AppRecord) -> bool:
    """Whether the installed app, as the service manager sees it, is stopped before it
    leaves (_replaced stops only an app that may run)."""
    return seen.status in ACTIVE


def _scripts(new: AppTarget) -> frozenset[str]:
    """The lifecycle scripts the app has (none for a scriptless app, whose unit lpam
    writes; all four when its folder was not read): a text names only these."""
    if new.command is not None or new.launch is not None:
        return frozenset()
    return LIFECYCLE_SCRIPTS if new.scripts is None else new.scripts


def _other(old: AppRecord, new: AppTarget, stops: bool) -> Reason:
    """Why another generation replaces the installed one."""
    if new.tree is None and new.repository == UNKNOWN:
        return KnownAfterFetch(new.name)
    if old.repository != new.repository:
        return Moved(new.name, old.repository, new.repository, stops)
    same_folder = new.tree == old.tree if new.tree is not None else new.commit == old.commit
    command = list(new.command) if new.command is not None else None
    same_how = (old.command, old.launch) == (command, new.launch)
    if same_folder and same_how:  # same generation, yet not on disk
        return FolderMissing(new.name, stops)
    folder = None if new.tree is None else (old.tree, new.tree)
    return NewGeneration(new.name, folder, not same_folder, old.params != new.params, stops)


def _replaced(old: AppRecord | None, new: AppTarget | None,
              generations: frozenset[GenerationKey], *, start: bool,
              verify: bool) -> list[Step]:
    """The installed generation (if any) stopped when it may be active and uninstalled,
    the new one (if any) staged while preparing, then installed and started."""
    steps: list[Step] = []
    gen = (new.generation or UNKNOWN) if new is not None else None
    if new is not None and gen is not None and GenerationKey.of(new.name, gen) not in generations:
        steps.append(on(StepKind.STAGE, f"{new.name}@{gen}", generation_of(new, gen),
                        good=new.proven, phase=Phase.PREPARE))
    if old is not None:
        target = f"{old.name}@{old.generation}"
        if old.status in ACTIVE:
            steps.append(on(StepKind.STOP, target, recorded(old)))
        steps.append(on(StepKind.UNINSTALL, target, recorded(old)))
    if new is not None and gen is not None:
        target = f"{new.name}@{gen}"
        steps.append(on(StepKind.INSTALL, target, generation_of(new, gen), good=new.proven))
        if start:
            steps += started(new, gen, target, verify=verify)
    return steps


def _same(old: AppRecord, seen: AppRecord, new: AppTarget, live: UnitState | None, *,
          start: bool, verify: bool) -> tuple[Reason, list[Step]]:
    """The installed generation is the wanted one: new parameters, an operator's hold, the
    service manager's word (`seen`: the record refreshed by it), a cut-off script, an
    unproven app."""
    target = f"{old.name}@{old.generation}"
    unit = live.describe() if live is not None else ""
    if (old.params, old.user) != (new.params, new.user):
        keys = tuple(sorted(k for k in set(old.params) | set(new.params)
                            if old.params.get(k) != new.params.get(k)))
        reinstall = seen.status in ("installing", "uninstalling")
        return (Reconfigure(new.name, keys, reinstall, start, _stops(seen), _scripts(new)),
                _reconfigured(seen, new, target, start=start, verify=verify))
    kinds = SAME_GENERATION[seen.status]
    if not start or seen.held:
        kinds = tuple(k for k in kinds if k is not StepKind.START)
        if seen.status in ("starting", "running"):
            kinds = (StepKind.STOP,)
    steps = [on(k, target, recorded(seen), good=seen.good) for k in kinds]
    checks = start and verify and not seen.held and not seen.good
    if checks:
        steps.append(verified(new, seen.generation, target))
    return _why(old, seen, new, unit, bool(kinds), checks, start=start), steps


def _why(old: AppRecord, seen: AppRecord, new: AppTarget, unit: str, acts: bool,
         checks: bool, *, start: bool) -> Reason:
    """Why the installed generation is left, finished or checked as it is."""
    if seen.held or not start:
        reinstall = seen.status in ("installing", "uninstalling")
        return Held(new.name, seen.status, may_run=acts and not reinstall,
                    operator=seen.held, scripts=_scripts(new))
    if seen.status == "stopping" and old.status != "stopping":
        return Unsupervised(new.name, unit)
    if old.status == "running" and seen.status == "installed":
        return NotRunning(new.name, unit, unproven=checks)
    if old.status == "installed" and seen.status == "running" and not checks:
        return StartedOutside(new.name, unit)
    if seen.status == "running":
        return Running(new.name, None if new.commit == old.commit else new.commit,
                       unproven=checks)
    return Finish(new.name, seen.status, unproven=checks, scripts=_scripts(new))


def _reconfigured(seen: AppRecord, new: AppTarget, target: str, *, start: bool,
                  verify: bool) -> list[Step]:
    """Stop it if it may run, record the new values (a unit lpam wrote is rewritten), finish
    a cut-off install, start it again. Nothing is fetched; with new parameters the app has
    to prove itself again."""
    wanted = generation_of(new, seen.generation)
    steps = []
    if seen.status in ACTIVE:
        steps.append(on(StepKind.STOP, target, recorded(seen)))
    steps.append(on(StepKind.CONFIGURE, target, wanted, good=new.proven))
    if seen.status in ("installing", "uninstalling"):
        steps.append(on(StepKind.INSTALL, target, wanted, good=new.proven))
    if start:
        steps += started(new, seen.generation, target, verify=verify)
    return steps


def _fields(name: str, repository: str, commit: str | None, params: dict[str, str],
            status: str | None) -> Fields:
    fields: Fields = {"name": name, "repository": repository, "commit": commit,
                      "params": dict(params)}
    if status is not None:
        fields["status"] = status
    return fields
