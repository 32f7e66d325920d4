"""The plan use case: resolve the desired state, observe the machine, make the plan.

A plan is exact: it fetches the commits it needs into the store's object database, under
the apply lock (a fetch is a write), never moving a checkout. Beside a running apply, or
offline, it plans from what is local and says so; such a plan cannot be saved. While a
rollback holds the machine, the plan proposes nothing — unless the rollback was cut off,
and then its steps are what finishes it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler import __version__
from reconciler.base.errors import LockError, LpamError
from reconciler.workflow.defaults import LOCK_TIMEOUT
from reconciler.workflow.events import Fetched, Note, Phase, Report
from reconciler.workflow.machine import Machine

if TYPE_CHECKING:
    from reconciler.adapters.git import GitStore
    from reconciler.core.planning.model import Targets
    from reconciler.engine.observe.targets import Fetch
    from schemas.desired import DesiredState
    from schemas.plan import FetchedRepository, Plan
    from schemas.record import StateRecord

# Imported inside functions: the planner and engine (pydantic; networkx when needed) load only
# when a plan is made; applying imports this module at top (start-up of its importers).


def plan(machine: Machine, path: Path, desired: DesiredState, *, report: Report,
         offline: bool = False, out: Path | None = None, lock_timeout: float | None = None,
         places: Sequence[tuple[int, int]] = ()) -> Plan:
    """`lpam plan`: exact when it can take the lock, from what is local beside a running
    apply (after waiting for it), at once beside a script an ended apply left running
    (said in a note), or when `offline`. `out` saves the plan (an exact one only).
    `places`: each desired app's (line, column) in `path` (a `DesiredDocument`'s), where
    a refusal names it; none for a desired state made in code (the file alone)."""
    from reconciler.engine.execution.lock import Holding, apply_lock, holder
    from reconciler.engine.observe.targets import Fetch

    if offline and out is not None:
        raise LpamError("an --offline plan cannot be saved: it may hold values known only "
                        "after a fetch", hint="drop --offline to save an exact plan")
    held = holder(machine.layout)
    # A script of an apply that has ended holds the lock until it ends, whenever that is:
    # no apply will release it, so a plan to read makes no one wait (one to save must).
    orphan = held is not None and Holding.of(held).orphaned and out is None
    busy = held if offline or orphan else None
    if not offline and not orphan:
        wait = LOCK_TIMEOUT if lock_timeout is None else lock_timeout
        if held is not None:  # say why the plan is silent meanwhile, in apply's words
            report(Note(f"waiting up to {wait:g} s for the apply lock, held by "
                        f"{Holding.of(held).describe()}"))
        try:
            with apply_lock(machine.layout, timeout=wait):
                _, made = prepare(machine, path, desired, fetch=Fetch.OBJECTS, report=report,
                                  places=places)
                if out is not None:
                    from reconciler.base.atomic import write_atomic

                    write_atomic(out, made.model_dump_json(indent=2) + "\n")
                return made
        except LockError:
            busy = holder(machine.layout)
            if out is not None or busy is None:
                raise
    return prepare(machine, path, desired, fetch=Fetch.OFFLINE, report=report, busy=busy,
                   places=places)[1]


def plan_file(machine: Machine, path: Path, *, report: Report, offline: bool = False,
              out: Path | None = None, lock_timeout: float | None = None) -> Plan:
    """`lpam plan [-f FILE]`: the desired state at `path` read (refused before any lock),
    then planned as `plan` does."""
    from reconciler.core.documents import load_desired_document

    document = load_desired_document(path)
    return plan(machine, path, document.desired, report=report, offline=offline, out=out,
                lock_timeout=lock_timeout, places=document.places)


def prepare(machine: Machine, path: Path, desired: DesiredState, *, fetch: Fetch,
            report: Report, busy: str | None = None,
            places: Sequence[tuple[int, int]] = ()) -> tuple[GitStore, Plan]:
    """Resolve the desired state, observe the machine and plan; `path` anchors relative
    URLs. `busy` is what holds the lock when the caller planned beside a running apply;
    `places` as `plan` takes them."""
    from dataclasses import replace

    from reconciler.core.planning.holds import hold_reason, released
    from reconciler.core.planning.plan import make_plan
    from reconciler.core.planning.settling import settling
    from reconciler.engine.observe.machine import asks_manager, observe
    from reconciler.engine.observe.targets import Fetch, fetched_note, resolve
    from reconciler.engine.records.legacy.appdir import libpanda_user
    from reconciler.engine.records.state import read_record

    layout = machine.layout
    store = machine.store()
    record = read_record(layout)
    if record.cutover is not None and record.cutover.rollback is not None:
        return store, _finishing_plan(machine, record, report)
    hold = hold_reason(record, desired)
    if hold is not None:  # a rollback holds: nothing to resolve, no network needed
        held = _held_plan(machine, store, record, hold, report)
        return store, held if busy is not None else settling(held, record)
    targets = resolve(desired, base_dir=path.resolve().parent, store=store, fetch=fetch,
                      default_user=libpanda_user(layout), root=layout.root,
                      notice=lambda text: report(Note(text)))
    refuse_shared_claims(path, places, targets)  # every plan and apply passes here
    report(Phase("resolve"))
    said = fetched_note(targets)
    if said is not None:
        report(Fetched(said))
    needs = any(a.deps.how for a in targets.apps)  # apt, pip or ROS
    observed = observe(layout, store, targets,
                       machine.services if asks_manager(record) else None,
                       machine.deps if needs else None)
    unheld, ended = released(observed.record, desired)  # an operator's stop may end
    for note in ended:
        report(Note(note))
    observed = replace(observed, record=unheld)
    report(Phase("observe"))
    if busy is not None:
        report(Note(busy_note(busy)))
    made = make_plan(targets, observed, now=machine.clock(), lpam_version=__version__,
                     offline=fetch is Fetch.OFFLINE)
    if busy is None:  # under the lock (or with no apply beside it): what it leaves owed ends
        made = settling(made, observed.record)
    made = made.model_copy(update={"fetched": fetched(targets)})
    report(Phase("plan"))
    if busy is None and observed.interrupted:
        report(Note(interrupted_note(observed.interrupted, made)))
    return store, made


def fetched(targets: Targets) -> list[FetchedRepository]:
    """What resolving fetched, per repository (ROS sources included), for `plan --json`."""
    from reconciler.engine.observe import targets as resolving
    from schemas.plan import FetchedRepository

    return [FetchedRepository(key=r.key, bytes=r.fetched or 0, shallow=r.fetched_alone)
            for r in resolving.fetched(targets)]


def busy_note(busy: str) -> str:
    """What a plan made beside the lock's holder says: who holds it, worded as `apply`
    words it (a script of an apply that has ended is no apply in progress), and that the
    plan fell back to what is local."""
    from reconciler.engine.execution.lock import Holding

    holding = Holding.of(busy)
    where = "as it stands now" if holding.orphaned else \
        "as it stands now, part-way through that apply"
    return (f"the apply lock is held by {holding.describe()}: this plan was made offline, "
            f"from what the store already holds (nothing fetched), and shows the machine "
            f"{where}")


def refuse_shared_claims(path: Path, places: Sequence[tuple[int, int]],
                         targets: Targets) -> None:
    """Two desired apps that claim one exclusive resource (core/planning/resources.py) are
    refused once their catalogs are read, before anything on the car changes, at the
    second app's place in the desired state at `path` and naming the first's (`places`:
    each app's (line, column) there, in the desired order, as `DesiredDocument` has them;
    an app without one is named by the file alone)."""
    from reconciler.core.planning.resources import Claim, Where, conflicts, refuse

    claims = []
    for index, app in enumerate(targets.apps):
        line, column = places[index] if index < len(places) else (None, None)
        claims.append(Claim(app.name, Where(path, line, column), app.resources))
    refuse(conflicts(claims))


def interrupted_note(interrupted: tuple[str, ...], made: Plan) -> str:
    """What the plan does about the steps the last apply was cut off in. A step's script
    may have finished after lpam died (its guard wrote the exit code): then the record is
    settled and that step is not run again."""
    cut = ", ".join(interrupted)
    planned = {s.id for s in made.steps}
    again = [s for s in interrupted if s in planned]
    if again:
        return (f"the last apply stopped during {cut}; the steps below finish it "
                f"({', '.join(again)} again)")
    if made.steps:
        return (f"the last apply stopped during {cut}; its script finished since, so "
                "it is not run again; the steps below finish the apply")
    return f"the last apply stopped during {cut}; its script finished since, so " \
        "nothing is left to redo"


def _held_plan(machine: Machine, store: GitStore, record: StateRecord, hold: str,
               report: Report) -> Plan:
    """While a rollback holds: the steps that finish it if it was cut off, else nothing."""
    from reconciler.core.planning.modes import held_plan, hold_targets
    from reconciler.engine.observe.machine import observe

    targets = hold_targets(record)
    finishing = None if targets is None else \
        (targets, observe(machine.layout, store, targets, machine.services))
    made, finishes = held_plan(record, hold, finishing, now=machine.clock(),
                               lpam_version=__version__)
    if finishes:
        back = ", ".join(f"{e.app} ({e.generation})"
                         for e in (record.hold.targets if record.hold else []))
        report(Note(f"the rollback to {back} was cut off; the steps below finish it"))
    return made


def _finishing_plan(machine: Machine, record: StateRecord, report: Report) -> Plan:
    """A rollback that a fault cut off is finished before anything else
    (core/planning/modes.py), each app's unit asked of its manager."""
    from reconciler.core.planning.modes import finished_to, finishing_plan
    from reconciler.engine.observe.machine import lives
    from reconciler.engine.records import generations

    made = finishing_plan(record, lives(record, machine.services),
                          generations.present(machine.layout), now=machine.clock(),
                          lpam_version=__version__)
    report(Note(f"a rollback {finished_to(record)} was cut off by a fault; the steps below "
                "finish it"))
    return made
