"""The agent's waves (issue 34): whether this car's turn has come to apply a new revision
of the fleet repository, from what the cars ahead of it published — no controller, git
hosting the only thing between the cars.

Place in a pass (workflow/sync.py): after the fetch, before the apply. The rules are
core/rollout.py's; this reads what they need:

- the rollout declared in this car's desired state at the revision (it travels with the
  revision it governs);
- the statuses of the cars in the waves before this car's: their `status/<vehicle>`
  branches, fetched in the pass's one fetch (`watch`: by the rollout the last pass
  waited on) or, when the revision brought another rollout, in a second fetch;
- whether the revision returns this car to a desired state it ran before: a revert in git
  is the fleet's rollback and never waits for a wave.

While a car waits, the pass stages the revision (fetches the commits it pins), so that its
turn applies with no network; it records `deferred` with the wave's reason, as a closed
update gate does, and publishes where it stands (schemas/rollout.py `RolloutState`).
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import ConfigError, GitError, LpamError
from reconciler.core.rollout import Peer, stage_of, turn, watched, wave_of
from reconciler.workflow.followed import followed
from reconciler.workflow.machine import Machine
from reconciler.workflow.source import SOURCE_KEY, desired_at
from schemas.rollout import RolloutSpec, RolloutState

if TYPE_CHECKING:
    from schemas.agent import AgentConfig, AgentStatus
    from schemas.desired import DesiredState
    from schemas.timeline import Stamp

# Imported inside functions: clone, publication, the lock and its defaults load only when
# a car waits and reads the others' statuses; a pass with no rollout never needs them.

STATUS_REFS = "refs/heads/status/"
REVERT_DEPTH = 16
"""How far back along the applied revision's first parents a revert is recognised."""

WAITING = frozenset({"waiting", "halted"})


def rollout_of(machine: Machine, config: AgentConfig, vehicle: str,
               revision: str | None) -> RolloutSpec | None:
    """The rollout this car's desired state declares at `revision`; None without one, or
    when the file cannot be read (the apply then says why, as without a rollout)."""
    found = None if revision is None else _desired(machine, config, vehicle, revision)
    return None if found is None else found.rollout


def watch(machine: Machine, config: AgentConfig, vehicle: str,
          status: AgentStatus) -> tuple[str, ...]:
    """The status branches (globs of vehicle ids) this pass's fetch brings too: those of
    the waves before this car's, while it waited at the last pass; none otherwise (a car
    that is not waiting reads no other car's status, and fetches none)."""
    last = status.rollout
    if last is None or last.stage not in WAITING:
        return ()
    spec = rollout_of(machine, config, vehicle, status.desired_revision)
    return () if spec is None else watched(spec, vehicle)


def held(machine: Machine, config: AgentConfig, spec: RolloutSpec, vehicle: str,
         revision: str, status: AgentStatus, *, fetched: tuple[str, ...] | None,
         now: datetime) -> RolloutState | None:
    """Where this car stands when it may not apply `revision` yet; None when it may (its
    turn came, or the revision returns it to what it ran before). `fetched`: the status
    branches this pass's fetch brought; None when the pass is offline: then the statuses
    the store holds answer, with no second try at the network (older statuses prove less,
    never more)."""
    if _returns(machine, config, vehicle, revision, status.applied_revision):
        return None
    needed = watched(spec, vehicle)
    if fetched is not None and needed and needed != fetched:
        _fetch_statuses(machine, config, needed)
    decided = turn(spec, vehicle, revision, peers(machine, config, vehicle), now)
    if decided.go:
        return None
    assert decided.stage is not None
    last = status.rollout
    same = last is not None and last.revision == revision and last.stage == decided.stage
    return RolloutState(revision=revision, wave=decided.wave, stage=decided.stage,
                        since=last.since if same and last is not None else _time(now),
                        reason=decided.reason)


def after(spec: RolloutSpec, vehicle: str, revision: str, result: str,
          reason: str | None, last: RolloutState | None, *, running: bool,
          stamp: Stamp) -> RolloutState | None:
    """Where this car stands after a pass that tried `revision` and ended in `result`.
    How long it has run the revision is counted on the boot's clock (`stamp`): since the
    apply, or since this boot began when the car rebooted since (its apps started again:
    the proof starts again with them)."""
    now = stamp.wall
    wave = wave_of(spec, vehicle)
    mine = last if last is not None and last.revision == revision else None
    if result in ("applied", "nothing to do"):
        kept = mine is not None and mine.applied is not None
        applied = mine.applied if mine is not None and mine.applied else _time(now)
        boot, mono = (mine.boot, mine.mono) if mine is not None and kept else \
            (stamp.boot, stamp.mono)
        if boot != stamp.boot or mono is None:
            boot, mono = stamp.boot, 0.0  # rebooted: counted from this boot's start
        stage, why = stage_of(spec, stamp.mono - mono, running=running)
        since = mine.since if mine is not None and mine.stage == stage else _time(now)
        return RolloutState(revision=revision, wave=wave, stage=stage, since=since,
                            reason=why, applied=applied, boot=boot, mono=mono)
    if result in ("rolled back", "failed"):
        since = mine.since if mine is not None and mine.stage == "rolled back" else _time(now)
        return RolloutState(revision=revision, wave=wave, stage="rolled back", since=since,
                            reason=reason)
    if result == "deferred":  # its turn came; an update gate holds it
        since = mine.since if mine is not None and mine.stage == "waiting" else _time(now)
        return RolloutState(revision=revision, wave=wave, stage="waiting", since=since,
                            reason=reason)
    return last  # stopped, offline: nothing new is known


def peers(machine: Machine, config: AgentConfig, vehicle: str) -> dict[str, Peer]:
    """The other cars as their status branches in this car's store show them."""
    from reconciler.adapters import clone
    from reconciler.core.publication import STATUS_FILE, read_status_file

    location = machine.store().location(SOURCE_KEY)
    try:
        _, files = clone.published(location, branch=config.source.branch,
                                   prefixes=(b"refs/remotes/origin/status/",),
                                   file=STATUS_FILE.encode())
    except ConfigError:
        return {}
    found: dict[str, Peer] = {}
    for each in files:
        if each.name == vehicle:
            continue
        reported = datetime.fromtimestamp(each.commit_time, timezone.utc)
        try:
            status = read_status_file(each.content,
                                      where=Path("status", each.name, STATUS_FILE))
        except ConfigError:
            status = None
        if status is None:  # unreadable: it reported, and says nothing lpam can use
            found[each.name] = Peer(each.name, reported)
            continue
        last = status.agent.last_attempt
        found[each.name] = Peer(
            each.name, reported, status.agent.rollout,
            None if last is None else (last.revision, last.result, last.reason))
    return found


def _fetch_statuses(machine: Machine, config: AgentConfig, globs: tuple[str, ...]) -> None:
    """Bring the status branches matching `globs`; offline, the ones the store holds
    answer (older: they prove less, never more)."""
    from reconciler.engine.execution.lock import apply_lock
    from reconciler.workflow.defaults import FETCH_LOCK_TIMEOUT

    try:
        with apply_lock(machine.layout, timeout=FETCH_LOCK_TIMEOUT):
            machine.store().fetch(SOURCE_KEY, config.source.url, skip=STATUS_REFS,
                                  keep=globs)
    except GitError:
        pass


def _returns(machine: Machine, config: AgentConfig, vehicle: str, revision: str,
             applied: str | None) -> bool:
    """Whether this car's desired state at `revision` is, but for its rollout, the one at
    the revision it applied or one of that revision's first parents: a revert."""
    if applied is None:
        return False
    wanted = _essence(machine, config, vehicle, revision)
    if wanted is None:
        return False
    for old in machine.store().ancestors(SOURCE_KEY, applied, limit=REVERT_DEPTH):
        if _essence(machine, config, vehicle, old) == wanted:
            return True
    return False


def _essence(machine: Machine, config: AgentConfig, vehicle: str,
             revision: str) -> str | None:
    """This car's desired state at `revision` but its rollout, to compare."""
    found = _desired(machine, config, vehicle, revision)
    return None if found is None else \
        found.model_copy(update={"rollout": None}).model_dump_json()


def _desired(machine: Machine, config: AgentConfig, vehicle: str,
             revision: str) -> DesiredState | None:
    """This car's desired state at `revision`; None without one or when it cannot be read."""
    name = followed(machine, vehicle, revision)
    try:
        found = None if name is None else desired_at(machine, config.source.url, revision,
                                                     name)
    except LpamError:
        return None
    return None if found is None else found.desired


def _time(now: datetime) -> str:
    return now.isoformat(timespec="seconds")
