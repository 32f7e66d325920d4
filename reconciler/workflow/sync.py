"""The sync use case: one pass of a vehicle following its desired-state repository.

fetch the source → pick this vehicle's file → validate → plan → apply → record. Each
phase fails on its own, and never at the running app's expense:

- no network: the last fetched revision is applied if it never was, else nothing is done
  (exit 0, "offline") — a car sees WiFi only at the start or the end of a trip;
- a document error or a failed apply (a health rollback included): the running app stays,
  the revision and the reason are recorded, and that revision is not tried again until a
  new one arrives — a broken commit must not restart the car's app every five minutes;
- `fetch_only`: fetch the source and the commits it pins, record, change nothing (the
  pass at shutdown, so that what WiFi brought at the end of a trip applies at the next
  start); pins that could not be fetched are recorded as such (offline, or failed when
  the desired state is at fault), never as fetched;
- a damaged copy in the repository store (the source's or an app repository's) is fetched
  anew, as apply does; with no network to do so the pass is "offline", not failed: the
  revision is not at fault, and the next pass with network tries it again.

Where the source's revision comes from — the network or a bundle file — is a
`DesiredStateSource` (workflow/source.py, with the relative `url:` paths of a desired
state resolved against the source repository's URL, as git resolves a submodule's).

What a pass applies is recorded as the agent's (workflow/actor.py), with the fleet
revision it applied: whoever started the pass (the agent's unit, `lpam sync` at a
terminal), the change is the fleet's.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.atomic import write_atomic
from reconciler.base.errors import (
    ConfigError,
    Deferred,
    GitError,
    HealthError,
    LpamError,
    PushRefusedError,
    StopRequested,
    StoreDamagedError,
    TrustError,
)
from reconciler.engine.records.state import read_override
from reconciler.workflow import waves
from reconciler.workflow.actor import agent
from reconciler.workflow.applying import ApplyOptions, apply
from reconciler.workflow.bundle import BundleFile
from reconciler.workflow.defaults import FETCH_LOCK_TIMEOUT, LOCK_TIMEOUT
from reconciler.workflow.events import Note, Progress, Report
from reconciler.workflow.followed import Followed as Followed
from reconciler.workflow.followed import desired_of as _desired
from reconciler.workflow.followed import followed, read_status, vehicle_id
from reconciler.workflow.machine import Machine
from reconciler.workflow.provenance import TIMELINE_FILE, published_timeline, stamp_finished
from reconciler.workflow.source import SOURCE_KEY, DesiredStateSource
from reconciler.workflow.source import join_url as join_url
from schemas.agent import (
    PASSES_KEPT,
    AgentConfig,
    AgentStatus,
    Attempt,
    Publication,
    Published,
    Result,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from schemas.override import LocalOverride
    from schemas.rollout import RolloutState
    from schemas.timeline import Stamp

# Imported inside functions: signatures, publication, targets and planning load only on the
# sync step that uses them (0-30 modules each, no heavy library); a small start-up gain.


@dataclass(frozen=True)
class Synced:
    """How a pass ended; `code` is the process exit code (0 applied, nothing to do or
    offline; 1 failed; 75 deferred by a closed gate, as `lpam apply`)."""

    result: Result
    revision: str | None
    reason: str | None = None
    hint: str | None = None

    @property
    def failed(self) -> bool:
        return self.result in ("failed", "rolled back")

    @property
    def code(self) -> int:
        return 1 if self.failed else Deferred.exit_code if self.result == "deferred" else 0


def sync(machine: Machine, config: AgentConfig, *, report: Report,
         options: ApplyOptions | None = None, fetch_only: bool = False,
         bundle: Path | None = None) -> Synced:
    """One pass; the outcome is recorded in `status.json` whatever it is, and published
    as the branch `status/<vehicle>` of the source when the source accepts pushes. With
    `bundle`, the source and what it pins come from that file instead of the network."""
    online: list[bool] = []
    machine.look()  # each pass writes what happened to the apps (after a boot: a power cut)
    stamp_data(machine, report)
    done = _pass(machine, config, report=report, options=options, fetch_only=fetch_only,
                 bundle=bundle, online=online)
    if online:
        publish(machine, config, report)
    return done


def stamp_data(machine: Machine, report: Report) -> None:
    """Each pass stamps the data files finished since the last one (bounded: a backlog
    takes several passes); a file it cannot stamp is said, and never stops the pass."""
    try:
        stamped = stamp_finished(machine.layout, now=time.time())
    except (OSError, LpamError) as exc:
        report(Note(f"data files not stamped this pass: {exc}"))
        return
    if stamped:
        report(Note(f"stamped {len(stamped)} data file(s) with the software that made them"))


def _pass(machine: Machine, config: AgentConfig, *, report: Report,
          options: ApplyOptions | None, fetch_only: bool, bundle: Path | None,
          online: list[bool]) -> Synced:
    options = options or ApplyOptions()
    status = read_status(machine)
    vehicle = vehicle_id(machine, config)
    source: DesiredStateSource = Remote() if bundle is None else BundleFile(bundle)
    watch = waves.watch(machine, config, vehicle, status)
    try:
        offline = source.bring(machine, config, report,
                               lock_timeout=options.lock_wait(FETCH_LOCK_TIMEOUT), keep=watch)
    except StoreDamagedError as exc:
        if not source.live:
            raise
        report(Note(f"offline: {exc.message}"))
        return _record(machine, status, Synced("offline", None, exc.message, exc.hint))
    if offline is None:
        online.append(True)
    revision = _tip(machine, config)
    status = status.model_copy(update={"vehicle": vehicle, "desired_revision": revision})
    if revision is None:
        why = offline or f"the source has no branch {config.source.branch!r}"
        return _record(machine, status, Synced("offline" if offline else "failed", None, why))
    status = status.model_copy(update={"follows": followed(machine, vehicle, revision)})
    if fetch_only:
        return _record(machine, status, _fetch_pins(machine, config, vehicle, revision, report))
    local = read_override(machine.layout)
    if local is not None:
        return _record(machine, status, _overridden(machine, local, revision, options=options,
                                                    report=report, offline=offline is not None))
    if offline and source.live and revision == status.applied_revision:
        return _record(machine, status, Synced("offline", revision, offline))
    if config.trust is not None:
        try:
            _trusted(machine, config, revision)
        except TrustError as exc:
            report(Note(f"revision {revision[:12]} refused: {exc.message}"))
            return _record(machine, status, Synced("failed", revision, exc.message, exc.hint))
    if status.failed(revision) and revision != status.applied_revision:
        report(Note(f"revision {revision[:12]} failed before; waiting for a new one"))
        return _record(machine, status, Synced("nothing to do", revision,
                                               "this revision failed before"))
    rollout = waves.rollout_of(machine, config, vehicle, revision)
    if rollout is not None and revision != status.applied_revision:
        wait = waves.held(machine, config, rollout, vehicle, revision, status,
                          fetched=watch if offline is None else None, now=machine.clock())
        if wait is not None:
            return _record(machine, status.model_copy(update={"rollout": wait}),
                           _staged(machine, config, vehicle, revision, wait, report))
    chosen = lambda: _desired(machine, config, vehicle, revision,  # noqa: E731
                              keep=frozenset(filter(None, [status.applied_revision])))
    done = _applied(machine, chosen, revision, options=replace(options, by=agent(revision)),
                    report=report, local=offline is not None)
    if done.result in ("applied", "nothing to do"):
        status = status.model_copy(update={"applied_revision": revision})
    if rollout is not None or status.rollout is not None:  # none: nothing to ask the apps
        status = status.model_copy(update={"rollout": None if rollout is None else waves.after(
            rollout, vehicle, revision, done.result, done.reason, status.rollout,
            running=_running(machine), stamp=_stamp(machine))})
    return _record(machine, status, done)


def _staged(machine: Machine, config: AgentConfig, vehicle: str, revision: str,
            wait: RolloutState, report: Report) -> Synced:
    """A car whose wave's turn has not come: the revision is staged (the commits it pins
    fetched), so that its turn applies with no network — unless the rollout is halted:
    that revision will not be applied here; the pass is deferred, as by a closed update
    gate, with the wave's reason."""
    reason = wait.reason or wait.stage
    report(Note(f"revision {revision[:12]} waits: {reason}"))
    if wait.stage == "halted":  # it will not be applied: nothing to stage
        return Synced("deferred", revision, reason)
    staged = _fetch_pins(machine, config, vehicle, revision, report)
    if staged.result != "fetched":
        reason += f" (not staged: {staged.reason})"
    return Synced("deferred", revision, reason)


def _stamp(machine: Machine) -> Stamp:
    """Now, on the boot's clock and the wall clock (a test's, where it plays the clock)."""
    from reconciler.engine.execution.provenance import stamp_now

    return stamp_now(machine.stamp, machine.clock)


def _running(machine: Machine) -> bool:
    """Whether every installed app runs (a rollout's proof needs it)."""
    from reconciler.report import status as machine_status

    seen = machine_status.report(machine.layout, state=machine.services.state, listed=False)
    return all(app.running for app in seen.installed)


def _applied(machine: Machine, choose: Callable[[], Followed], revision: str | None, *,
             options: ApplyOptions, report: Report, local: bool, why: str | None = None
             ) -> Synced:
    """Apply the desired state `choose` reads; how it ended, as this pass records it
    (`revision`: the source's revision the attempt is recorded against, None for a local
    override's, which must never mark a fleet revision as failed)."""
    try:
        chosen = choose()
        done = apply(machine, chosen.label, chosen.desired, options=options,
                     confirm=lambda plan: True, report=report, local=local,
                     base_dir=chosen.base_dir, places=chosen.places)
    except StopRequested as exc:  # not a failure: the next pass tries the revision again
        return Synced("stopped", revision, exc.message)
    except Deferred as exc:  # prepared, not cut over: the next pass tries again
        report(Note(exc.message))
        return Synced("deferred", revision, exc.message)
    except StoreDamagedError as exc:  # and no network to fetch it anew
        return Synced("offline", revision, exc.message, exc.hint)
    except LpamError as exc:
        failed: Result = "rolled back" if isinstance(exc, HealthError) else "failed"
        return Synced(failed, revision, _reason(exc), exc.hint)
    outcome: Result = "applied" if done.steps else "nothing to do"
    what = f"revision {revision[:12]}" if revision is not None else "the local override"
    report(Progress(f"{outcome}: {what} ({done.app})"))
    return Synced(outcome, revision, why)


def _overridden(machine: Machine, local: LocalOverride, revision: str, *,
                options: ApplyOptions, report: Report, offline: bool) -> Synced:
    """A local override is in force (workflow/override.py): the pass applies the local
    file, not the fleet's — which finishes an edit a power cut interrupted, and leaves one
    that was applied as it is — and the fleet's revision waits for the override's end."""
    from reconciler.core.documents import load_desired_document

    path = machine.layout.desired_state
    why = (f"local override ({local.by}, since {local.since}): the fleet's revision "
           f"{revision[:12]} waits until `lpam apply --release` or the phone's update")
    report(Note(why))
    return _applied(machine, lambda: Followed.of(load_desired_document(path),
                                                 path.resolve().parent),
                    None, options=replace(options, by=agent(None)), report=report,
                    local=offline, why=why)


def _trusted(machine: Machine, config: AgentConfig, revision: str) -> str:
    """The signer of `revision`, which must be listed in the allowed signers."""
    from reconciler.adapters.signatures import verify

    assert config.trust is not None
    allowed = machine.layout.under(config.trust.allowed_signers)
    signature, payload = machine.store().signature(SOURCE_KEY, revision)
    return verify(signature, payload, allowed, what=f"commit {revision[:12]}")


def _reason(exc: LpamError) -> str:
    """The error as one line, where it is included (file:line:column of a document)."""
    return f"{exc.where}: {exc.message}" if isinstance(exc, ConfigError) else exc.message


STATUS_PREFIX = "status/"


def publish(machine: Machine, config: AgentConfig, report: Report) -> None:
    """Push this vehicle's status to `status/<vehicle>` of the source when it is due
    (reconciler/core/publication.py: changed, or the heartbeat), so that `lpam fleet status` in
    any clone shows the whole fleet from git alone, and who made each car's last change;
    an unchanged status costs no connection and no commit. The branch holds at most
    `HISTORY` commits. A source that refuses pushes (a read-only mirror, a token without
    write access) costs a note, nothing more: the car keeps working and its status stays
    local. The push is made under the apply lock, as every write to the store is (a kill
    mid-write leaves a lock file only the lock's holder may sweep); when an apply holds it
    longer than LOCK_TIMEOUT, the status waits for the next pass."""
    from reconciler.core.publication import (
        STATUS_FILE,
        due,
        fingerprint,
        last_change,
        status_file,
    )
    from reconciler.engine.execution.lock import apply_lock
    from reconciler.engine.records.state import read_record
    from reconciler.report import status as machine_status

    own = read_status(machine)
    if own.vehicle is None:
        return
    seen = machine_status.report(machine.layout, state=machine.services.state, listed=False)
    every = [a.published() for a in seen.installed]
    now = machine.clock()
    local = read_override(machine.layout)
    change = last_change(read_record(machine.layout).history)
    # the timeline goes beside the status, in the same commit and push: a change of it
    # alone (a crash the manager restarted) is a change worth publishing
    timeline = published_timeline(machine.layout, own.vehicle)
    mark = hashlib.sha256((fingerprint(own, every, local, change) + timeline.mark).encode()
                          ).hexdigest()
    why = due(own.publication, mark, now, heartbeat=config.heartbeat_seconds)
    if why is None:
        return
    branch = STATUS_PREFIX + own.vehicle
    result: Published = "pushed"
    reason = None
    try:
        with apply_lock(machine.layout, timeout=LOCK_TIMEOUT) as lock:  # a push is a write
            lock.note("publishing this car's status")
            _push(machine, config, branch, {
                STATUS_FILE: status_file(own, every, local, change),
                TIMELINE_FILE: timeline.content},
                when=int(now.timestamp()), report=report)
        report(Progress(f"status published to {branch} ({why})"))
    except PushRefusedError as exc:
        result, reason = "refused", exc.message
        report(Note(f"status not published: the fleet repository is read-only for this car "
                    f"— {exc.message}. The car keeps working; its status stays local "
                    "(`lpam status`) and is offered again when it changes or in "
                    f"{config.heartbeat_seconds / 3600:g} h"))
    except LpamError as exc:
        result, reason = "failed", exc.message
        report(Note(f"status not published: {exc.message}. The car keeps working; its "
                    "status stays local (`lpam status`) and is offered again next pass"))
    done = Publication(time=now.isoformat(timespec="seconds"), fingerprint=mark,
                       result=result, reason=reason)
    write_atomic(machine.layout.agent_status,
                 own.model_copy(update={"publication": done}).model_dump_json(indent=2) + "\n")


def _push(machine: Machine, config: AgentConfig, branch: str, files: dict[str, bytes], *,
          when: int, report: Report) -> None:
    """One status commit on `branch`, on top of its tip while it holds fewer than `HISTORY`
    commits, else starting it afresh. A server that refuses to rewrite the branch (git's
    receive.denyNonFastForwards, a protected branch) gets it on top after all: a status
    published with a growing history is better than none."""
    from reconciler.core.publication import HISTORY, keeps_parent

    store = machine.store()
    length = store.history_length(SOURCE_KEY, branch, limit=HISTORY)
    keep = keeps_parent(length)
    vehicle = branch.removeprefix(STATUS_PREFIX)
    try:
        store.push_files(SOURCE_KEY, config.source.url, branch, files,
                         f"status of {vehicle}", when=when, parent=keep)
    except PushRefusedError:
        if keep or length == 0:
            raise
        store.push_files(SOURCE_KEY, config.source.url, branch, files,
                         f"status of {vehicle}", when=when, parent=True)
        report(Note(f"the fleet repository does not let this car rewrite {branch}, so its "
                    f"history grows past {HISTORY} commits: allow non-fast-forward pushes "
                    "to status/* (see the README's fleet section)"))


class Remote:
    """The source's URL, fetched over the network."""

    live = True

    def bring(self, machine: Machine, config: AgentConfig, report: Report, *,
              lock_timeout: float, keep: tuple[str, ...] = ()) -> str | None:
        """Fetch the source under the lock (a fetch is a write); the reason when offline."""
        from reconciler.engine.execution.lock import apply_lock
        from reconciler.engine.observe.targets import sound_copy

        try:
            with apply_lock(machine.layout, timeout=lock_timeout):
                store = machine.store()
                sound_copy(store, SOURCE_KEY, config.source.url, renew=True,
                           notice=lambda text: report(Note(text)))
                # the other cars' status branches are not this car's business, but
                # for those of the waves before its own while it waits (workflow/waves.py)
                store.fetch(SOURCE_KEY, config.source.url,
                            skip="refs/heads/" + STATUS_PREFIX, keep=keep)
        except StoreDamagedError:
            raise  # its copy cannot be read: `_pass` records the pass as offline
        except GitError as exc:
            report(Note(f"offline: {exc.message}"))
            return exc.message
        return None


def _tip(machine: Machine, config: AgentConfig) -> str | None:
    """The followed branch's commit as the last fetch from this source saw it."""
    store = machine.store()
    if store.origin_url(SOURCE_KEY) != config.source.url:
        return None  # fetched from another source before: not this one's revision
    refs = store.local_refs(SOURCE_KEY)
    return None if refs is None else refs.resolve(config.source.branch)


def _fetch_pins(machine: Machine, config: AgentConfig, vehicle: str, revision: str,
                report: Report) -> Synced:
    """Bring the commits the desired state pins into the store (objects only), so that the
    next start can apply with no network. When they cannot be fetched the pass says so, as
    a whole pass would: offline when git could not reach them (the revision is not at
    fault, the next pass tries again), failed when the desired state itself is at fault."""
    from reconciler.workflow.planning import plan

    try:
        chosen = _desired(machine, config, vehicle, revision)
        plan(machine, chosen.label, chosen.desired, report=report, places=chosen.places)
    except GitError as exc:
        report(Note(f"offline: {exc.message}"))
        return Synced("offline", revision, "the source was fetched; the commits it pins "
                      f"were not: {exc.message}", exc.hint)
    except LpamError as exc:
        return Synced("failed", revision, "the source was fetched; the commits it pins "
                      f"were not: {_reason(exc)}", exc.hint)
    return Synced("fetched", revision)


def _record(machine: Machine, status: AgentStatus, outcome: Synced) -> Synced:
    from reconciler.base.atomic import write_atomic

    attempt = Attempt(time=machine.clock().isoformat(timespec="seconds"),
                      revision=outcome.revision, result=outcome.result,
                      reason=outcome.reason)
    updated = status.model_copy(update={
        "last_attempt": attempt if outcome.result != "nothing to do" or outcome.reason is None
        else status.last_attempt,
        "passes": [*status.passes, attempt][-PASSES_KEPT:],
    })
    write_atomic(machine.layout.agent_status, updated.model_dump_json(indent=2) + "\n")
    return outcome
