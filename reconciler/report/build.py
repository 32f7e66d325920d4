"""The status report, built by one pure function from what reconciler/report/gather.py
read (and, where a face shows them, the plan and the gates): every face renders this value.

Every installed app is in it (a car may run a controller beside a recorder and a tracker,
issue 22), each with its generation, its claims and its unit now. Whether an app runs is
asked of its service manager (the live state), not taken from the record: the record says
what lpam last did, the manager what runs now. Where the manager cannot know the app's
unit, the record's word is shown, marked unverified.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from reconciler.base.unit import unit_name
from reconciler.core.planning.holds import release_command, same_set
from reconciler.core.planning.model import app_folder
from reconciler.report.exposure import exposed
from schemas.report import (
    CatalogRow,
    Checkout,
    Deferral,
    HoldView,
    InstalledApp,
    LastApplyState,
    LastApplyView,
    PlanView,
    RepositoryView,
    Standing,
    StatusReport,
    StrayFate,
    StrayView,
    UnitView,
)

if TYPE_CHECKING:
    from reconciler.base.unit import UnitState
    from reconciler.report.gather import Listing, Seen
    from schemas.catalog import CatalogApp
    from schemas.plan import Plan
    from schemas.record import Actor, AppRecord, LastApply, StateRecord, Stray

DAMAGED = "(damaged in the store: the next `lpam apply` fetches it anew)"


def build(seen: Seen, *, plan: Plan | str | None = None,
          gates: str | None = None) -> StatusReport:
    """The car now, as every face tells it; `plan`: what an apply would do now, or why
    that is not known."""
    record = seen.record
    last = record.last_apply
    state = None if last is None else last_state(last, alive=seen.alive)
    return StatusReport(
        installed=[_installed(a, seen.lives.get(a.name), rolled_back=held_by(record),
                              underway=seen.alive) for a in record.apps],
        service_manager=seen.manager,
        last_apply=None if last is None or state is None else LastApplyView(
            **last.model_dump(), state=state, shown=last_shown(last, alive=seen.alive)),
        repositories=[RepositoryView(key=r.key, url=r.url, ref=r.ref, commit=r.commit)
                      for r in record.repositories],
        checkouts_not_running=[Checkout(key=r.key, commit=r.commit, applied_commit=r.applied)
                               for r in record.repositories if r.applied != r.commit],
        holds=holds(record),
        apps=[row for listing in seen.listings for row in _rows(listing, seen)],
        strays=[_stray(s, seen) for s in record.strays],
        cutover=record.cutover, serial=record.serial, lineage=record.lineage,
        agent=seen.agent, override=seen.override, deferred=_deferral(last),
        plan=_plan(plan), gates=gates,
        exposed=[] if seen.files is None else exposed(seen.files),
        bluetooth=seen.bluetooth,
    )


def _plan(plan: Plan | str | None) -> PlanView | None:
    if plan is None or isinstance(plan, str):
        return None if plan is None else PlanView(summary=plan)
    return PlanView(summary=plan.summary or "no changes", changes=list(plan.changes))


def running(app: AppRecord, live: UnitState | None) -> tuple[bool, bool]:
    """(runs, verified): the manager's answer when it knows the unit, else the record's."""
    if live is not None and live.known:
        return live.running, True
    return app.running, False


def standing(app: AppRecord, live: UnitState | None) -> Standing:
    """The app's status in one closed word, from the same answer as whether it runs
    (`running`): a word and the Running column cannot disagree. An operator's stop and a
    script under way are lpam's own facts; whether it runs is the manager's, and where
    the manager cannot know its unit, the word says so (`unverified`)."""
    runs, verified = running(app, live)
    if app.held:
        return "stopping" if runs or app.status != "installed" else "stopped by operator"
    if app.status in ("installing", "starting"):
        return "starting"
    if app.status in ("stopping", "uninstalling"):
        return "stopping"
    if not verified:
        return "unverified"
    if runs:
        return "running"
    return "not running" if app.status == "running" else "installed"


def said(app: AppRecord, live: UnitState | None, *, rolled_back: str = "",
         underway: bool = False) -> str:
    """`standing` as a person needs it: what lpam did, what is still owed and by which
    command. While a rollback holds, plans propose nothing: no text promises the next
    apply's work then. `underway`: an apply lives, so a step it began is under way, not
    cut off (never both: the last apply's line says which)."""
    word = standing(app, live)
    owed = rolled_back

    def then(work: str) -> str:
        return f"{word} ({owed or work})"

    if word == "stopped by operator":
        return word if not owed else then("")
    if word in ("stopping", "starting"):
        runs, verified = running(app, live)
        unsure = f"; unverified: recorded {app.status}" if runs and not verified else ""
        verb = {"installing": "install", "starting": "start", "uninstalling": "uninstall"}\
            .get(app.status, "stop")
        if underway:
            return then(f"{_step(app, verb)} under way: the apply in progress does it") + unsure
        if app.held:
            return then("an operator's stop did not finish: the next apply stops it") + unsure
        # how it ended (a kill, Ctrl-C, a failure) is the last apply's line: the row says
        # only what is owed, so that it never contradicts that line
        return then(f"{_step(app, verb)} did not finish: the next apply finishes it") + unsure
    if word == "not running":
        return then("drift: the next apply starts it")
    if word == "installed":
        return then("not running: the next apply starts it")
    text = f"unverified: recorded {app.status}" if word == "unverified" else word
    if live is not None and live.known and not live.supervised:
        text += "; its service manager died: the next apply restarts it under a new one"
    elif not app.good:
        text += "; health not proven yet: the next apply checks it"
    return f"{text}; {owed}" if owed else text


def _step(app: AppRecord, verb: str) -> str:
    """A lifecycle step named as the app has it: its script, or — for an app lpam runs
    as a unit of its own (`command:`, `launch:`), which has no scripts — lpam's step."""
    if app.command is not None or app.launch is not None:
        return f"its {verb}"
    return f"{verb}.sh"


def _installed(app: AppRecord, live: UnitState | None, *, rolled_back: str,
               underway: bool) -> InstalledApp:
    runs, verified = running(app, live)
    unit = None if live is None else UnitView(
        name=live.name, known=live.known, active=live.active, sub=live.sub,
        restarts=live.restarts, pid=live.pid, supervised=live.supervised,
        said=live.describe())
    return InstalledApp(
        name=app.name, repository=app.repository, commit=app.commit,
        generation=app.generation, params=app.params, running=runs, verified=verified,
        status=app.status, standing=standing(app, live),
        said=said(app, live, rolled_back=rolled_back, underway=underway), held=app.held,
        rollback_hold=bool(rolled_back), good=app.good, unit=unit, command=app.command,
        launch=app.launch, user=app.user, claims=sorted(app.claims),
        claims_known=app.resources is not None)


def _stray(stray: Stray, seen: Seen) -> StrayView:
    """An app installed without a record, and what the next apply does with it: what the
    plan decides from the same observation (gather.taken_over)."""
    adopted_as = next((app for app, name in seen.adopt.items() if name == stray.name), None)
    fate: StrayFate = "adopted" if adopted_as is not None else \
        "known after fetch" if stray.folder is not None and not seen.decided else "replaced"
    return StrayView(name=stray.name, generation=stray.generation, stopped=stray.stopped,
                     pending=stray.pending, fate=fate, adopted_as=adopted_as)


def _rows(listing: Listing, seen: Seen) -> list[CatalogRow]:
    """A repository's rows: one per app, or one note."""
    if listing.note is not None or listing.damage is not None:
        note = listing.note if listing.note is not None else DAMAGED
        return [CatalogRow(repository=listing.repository, ref=listing.ref,
                           commit=listing.commit, app="-", service="-", installed=False,
                           running=False, status=None, description=note,
                           damage=listing.damage)]
    return [_row(listing, app, seen) for app in listing.apps]


def _row(listing: Listing, app: CatalogApp, seen: Seen) -> CatalogRow:
    mine = seen.record.installed(app.name)
    if mine is None or mine.repository != listing.repository:
        return CatalogRow(repository=listing.repository, ref=listing.ref,
                          commit=listing.commit, app=app.name, service=service_of(app),
                          installed=False, running=False, status=None,
                          description=app.description)
    live = seen.lives.get(mine.name)
    runs, verified = running(mine, live)
    return CatalogRow(repository=listing.repository, ref=listing.ref,
                      commit=mine.commit[:12], app=app.name,
                      service=mine.service or service_of(app), installed=True,
                      running=runs, status=mine.status, standing=standing(mine, live),
                      said=said(mine, live, rolled_back=held_by(seen.record),
                                 underway=seen.alive),
                      description=app.description, verified=verified)


def service_of(app: CatalogApp) -> str:
    """The service an app runs as, installed or not: the unit lpam writes for a scriptless
    app (named after its folder, as staging names it), else the one its `service` file
    names; `-` when it names none. Before, an app not installed showed none of lpam's
    units, so LPAM's table had an empty Service for every scriptless app not installed."""
    if app.command is not None or app.launch is not None:
        return unit_name(app_folder(app.path))
    return app.service or "-"


def reached(record: StateRecord) -> bool:
    """Whether the rollback that holds reached the set it returns to (a step that failed
    or a fault left it short: then plans finish it, workflow/planning.py). A hold that
    names no set (an older lpam's) cannot be finished: taken as reached, as plans do."""
    hold = record.hold
    return hold is None or not hold.targets or same_set(hold.targets, record.apps)


def held_by(record: StateRecord) -> str:
    """What a rollback's hold owes an installed app, said ("": no rollback holds)."""
    if record.hold is None:
        return ""
    if reached(record):
        return "held by `lpam rollback`"
    return "held by `lpam rollback`, which did not finish: the next apply finishes it"


def asked_by(actor: Actor | None) -> str:
    """Who asked for a hold, as status says it (nothing when not recorded)."""
    return "" if actor is None else f" (asked by {actor.shown})"


def holds(record: StateRecord) -> list[HoldView]:
    """Every hold on this car, what it holds against and how it ends."""
    against = record.desired.source if record.desired is not None else "the desired state"
    release = release_command(record)
    found = []
    if record.hold is not None:
        what = (f"`lpam rollback` returned to generation {record.hold.name}, and plans "
                "propose nothing else") if reached(record) else (
            f"the rollback to generation {record.hold.name} did not finish (a step failed "
            f"or it was cut off): the next `{release.removesuffix(' --release')}` finishes "
            "it, and then plans propose nothing else")
        found.append(HoldView(
            kind="rollback", what=what, against=against,
            ends=f"when the desired state last applied ({against}) changes, or with "
            f"`{release}`"))
    start = "`lpam start`" if len(record.apps) <= 1 else "`lpam start {name}`"
    for app in record.apps:  # an operator's stop holds one app
        if app.held:
            found.append(HoldView(
                kind="operator stop", what=f"{app.name} was stopped by `lpam stop`"
                f"{asked_by(app.held_by)} and stays stopped", against=against,
                ends=f"with {start.format(name=app.name)}, when the desired state last "
                f"applied ({against}) changes, or with `{release}`"))
    return found


def last_state(last: LastApply, *, alive: bool) -> LastApplyState:
    """The last apply's one state now: the record's result, except that an apply `in
    progress` whose process is gone was cut off (`alive`: its process lives and holds
    the lock, reconciler/report/gather.py)."""
    if last.result == "in progress":
        return "in progress" if alive else "cut off"
    if last.result == "applied":
        return "succeeded"
    return last.result


def last_shown(last: LastApply, *, alive: bool) -> str:
    """The last apply as it stands, said from its one state: a cut-off one says how to go
    on; a deferred one which gates were closed and what tries again — never to resume a
    desired state that may no longer be the one wanted."""
    state = last_state(last, alive=alive)
    why = f": {last.reason}" if last.reason else ""
    if state == "in progress":
        return f"in progress since {last.time} (pid {last.pid})"
    if state == "cut off":
        return (f"cut off (began {last.time}; lpam was killed or the power failed): "
                f"`{last.command or 'lpam apply'}` goes on from where it stood")
    if state == "deferred":
        return (f"deferred at {last.time}: the update gates were closed{why}; nothing on "
                f"the running app changed; {retry_said(last.retry)}")
    again = f"; `{last.command}` goes on from where it stood" \
        if state == "interrupted" and last.command else ""
    return f"{last.result} at {last.time}{why}{again}"


def retry_said(retry: str | None) -> str:
    """What tries a deferred apply again, and when."""
    if retry is not None:
        return f"the agent's next pass tries again at about {retry}"
    return "the next `lpam apply` tries again (`lpam gates` shows the gates now)"


def _deferral(last: LastApply | None) -> Deferral | None:
    """The last apply, if the gates deferred it: the record's word, so that any apply
    after it (one with nothing to do included) ends it."""
    if last is None or last.result != "deferred":
        return None
    return Deferral(time=last.time, reason=last.reason or "", gates=list(last.gates),
                    retry=last.retry)
