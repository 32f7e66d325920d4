"""When a car publishes its status to the fleet repository, and how much history it keeps:
the pure rules behind workflow/sync.py `publish` (no I/O, no clock of their own, no git).

Place in the flow: after a pass that reached the source (its fetch, one ref advertisement,
succeeded), the agent asks `due` whether its status must go to the branch
`status/<vehicle>`; only then does it open a second connection, a push. A pass that
changed nothing costs one connection and no commit, where every pass used to cost two
connections and one commit (100 cars every 5 minutes: 28,800 commits a day).

What counts as a change (`essentials`), exactly:

- the vehicle id, the file of the source it follows, the revision it would apply and the
  revision it applied;
- the last pass's revision and result, where `applied` and `nothing to do` count as one
  (both say "this car runs that revision as desired": a pass with nothing to do after one
  that applied is no news), and its reason, except a deferral's: that names the seconds
  and the speed of the moment ("stationary for 12 s") and would make every deferred pass
  news; that the pass was deferred still counts;
- the app: its name, generation, lifecycle status and whether it runs — with several
  apps installed, each app's (with one app or none the essentials are what they were, so
  a car upgraded to an lpam that knows several apps publishes nothing new for it);
- a local override (a phone's or libpanda-app-manager's edit): who, since when, how many
  edits.
- the last change the car's history records (`last_change`): when, what it made current,
  how it ended and who asked for it — counted only once there is one, so a car with no
  history publishes nothing new for it;
- where the car stands in a rollout (issue 34): the revision, its wave and stage, and why
  it was halted or rolled back — not how long it has waited or run, so `proven` is news
  and the seconds before it are not (counted only with a rollout).

Not counted: the times of the passes and their list (every pass adds one), and the last
publication itself.

When (`due`): the first time; when the essentials differ from the last attempt's; when the
heartbeat (agent.yaml `heartbeat_seconds`) has passed since the last attempt, so that a
quiet car is still seen alive; and at the next pass after an attempt that `failed` (the
network, not the repository). A repository that `refused` the push (read-only, no write
access for this car) is asked again only at the next change or heartbeat, not every pass.
A clock that went back (a Pi has no real-time clock) makes the heartbeat due at once
rather than never.

How much history (`keeps_parent`): each publication is one commit on `status/<vehicle>`,
on top of the last while the branch holds fewer than `HISTORY` commits; the next one
starts the branch afresh, with no parent, and the car pushes it over its own branch (a
non-fast-forward push). A status branch thus holds 1 to `HISTORY` commits however long the
car runs. Rewriting is safe there, unlike on a shared branch: only this car writes
`status/<vehicle>`, nothing is built on it, and `lpam fleet status` reads only its tip; the
dropped commits become unreachable and the server's garbage collection removes them.

What is published (`status_file`, read back by `read_status_file`): one file, `status.json`,
a typed and versioned document (schemas/fleet.py `CarStatus`); the files of cars that
published before it had a version are read through its migration. `app` is the first
installed app; a car running several apps also writes `apps`, every one of them.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from reconciler.base.errors import ConfigError
from schemas.agent import AgentStatus, Publication
from schemas.fleet import CarStatus, LastChange, PublishedApp
from schemas.kinds import DocumentKind
from schemas.override import LocalOverride
from schemas.record import HistoryEntry, history_sets

# Imported inside functions: the migrations (no heavy library, ~18 modules) load only when a
# published status file is read (`lpam fleet`); a small start-up gain.

STATUS_FILE = "status.json"
"""The file a car publishes on `status/<vehicle>`."""

HISTORY = 10
"""The most commits a status branch holds: the last few reports stay readable with
`git log status/<vehicle>`, and a year of heartbeats does not pile up in every clone."""

CONVERGED = frozenset({"applied", "nothing to do"})
"""Pass results that say the same thing about the car: it runs the revision as desired."""

VOLATILE_REASONS = frozenset({"deferred"})
"""Results whose reason changes from pass to pass (gate readings) and so does not count."""

def _several(apps: Sequence[PublishedApp]) -> list[dict[str, Any]] | None:
    """What the fleet sees of every installed app, or None with one app or none (then
    `app` says it all, as before several apps)."""
    if len(apps) <= 1:
        return None
    return [a.model_dump(mode="json") for a in apps]


def last_change(history: Sequence[HistoryEntry]) -> LastChange | None:
    """The newest set of the car's history (the apps one apply made current, or rolled
    back) as the fleet sees it, and who asked for it; None before any change."""
    sets = history_sets(list(history))
    if not sets:
        return None
    newest = sets[-1]
    return LastChange(time=newest[0].time, result=newest[0].result,
                      apps=[f"{e.app}@{e.generation}" for e in newest], by=newest[0].by)


def essentials(status: AgentStatus, apps: Sequence[PublishedApp],
               override: LocalOverride | None = None,
               change: LastChange | None = None) -> dict[str, Any]:
    """What of this status counts as a change: see the module docstring. `apps`: every
    installed app, in the order they were installed (the first is `app`)."""
    last = status.last_attempt
    attempt = None
    if last is not None:
        result = "converged" if last.result in CONVERGED else last.result
        reason = None if last.result in VOLATILE_REASONS else last.reason
        attempt = {"revision": last.revision, "result": result, "reason": reason}
    found: dict[str, Any] = {
        "vehicle": status.vehicle,
        "follows": status.follows,
        "desired_revision": status.desired_revision,
        "applied_revision": status.applied_revision,
        "last_attempt": attempt,
        "app": apps[0].model_dump(mode="json") if apps else None,
        "override": None if override is None else {"since": override.since, "by": override.by,
                                                   "edits": override.edits},
    }
    several = _several(apps)
    if several is not None:
        found["apps"] = several
    if status.rollout is not None:  # its stage, not the seconds it has run or waited
        state = status.rollout
        found["rollout"] = {"revision": state.revision, "wave": state.wave,
                            "stage": state.stage, "reason": state.reason
                            if state.stage in ("halted", "rolled back") else None}
    if change is not None:
        found["last_change"] = change.model_dump(mode="json")
    return found


def fingerprint(status: AgentStatus, apps: Sequence[PublishedApp],
                override: LocalOverride | None = None,
                change: LastChange | None = None) -> str:
    """A digest of the essentials: equal exactly when nothing that counts changed."""
    text = json.dumps(essentials(status, apps, override, change), sort_keys=True,
                      separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def due(last: Publication | None, mark: str, now: datetime, *,
        heartbeat: float) -> str | None:
    """Why this status must be published now (`first`, `changed`, `retry`, `heartbeat`),
    or None when the pass publishes nothing. `mark` is this status's fingerprint, `now`
    the time of the pass, `heartbeat` the agent's `heartbeat_seconds`."""
    if last is None:
        return "first"
    if last.fingerprint != mark:
        return "changed"
    if last.result == "failed":
        return "retry"
    try:
        then = datetime.fromisoformat(last.time)
        elapsed = (now - then).total_seconds()
    except (ValueError, TypeError):  # unreadable, or naive against aware: no trust in it
        return "heartbeat"
    if elapsed >= heartbeat or elapsed < 0:
        return "heartbeat"
    return None


def keeps_parent(length: int, bound: int = HISTORY) -> bool:
    """Whether the next status commit goes on top of the branch's tip (which holds `length`
    commits, 0 without one) or starts the branch afresh, so that it never holds more than
    `bound` commits."""
    return 0 < length < bound


def status_file(status: AgentStatus, apps: Sequence[PublishedApp],
                override: LocalOverride | None = None,
                change: LastChange | None = None) -> bytes:
    """The file a car publishes: its agent's status, what the fleet sees of its app (the
    first installed) and, when several are installed, of every app, a local override
    in force, and its last change with who asked for it. A car with one app or none
    writes no `apps`: its file is what it was."""
    several = list(apps) if len(apps) > 1 else []
    document = CarStatus(agent=status, app=apps[0] if apps else None, override=override,
                         apps=several, last_change=change)
    body = document.model_dump(mode="json", exclude=set() if several else {"apps"})
    return (json.dumps(body, indent=2, sort_keys=True) + "\n").encode("utf-8")


def read_status_file(content: bytes, *, where: Path) -> CarStatus | None:
    """A car's published status, brought to the current version; None when the file is no
    JSON at all (nothing to show), ConfigError naming `where` when it is JSON but not a
    status this lpam reads (damaged, or a newer lpam's)."""
    from migrations import upgrade

    try:
        data = json.loads(content)
    except (ValueError, RecursionError):
        return None
    if isinstance(data, dict) and "version" not in data:
        data = {**data, "version": 0}  # published before the file had a version
    data = upgrade(DocumentKind.CAR_STATUS, data, path=where)
    try:
        return CarStatus.model_validate(data)
    except ValidationError as exc:
        error = exc.errors()[0]
        field = ".".join(str(p) for p in error["loc"])
        raise ConfigError(f"invalid car's status at {field}: {error['msg']}", path=where,
                          hint="the car publishes a new one with its next status") from None
