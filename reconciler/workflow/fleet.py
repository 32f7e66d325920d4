"""`lpam fleet status`: the whole fleet from git alone.

Each car publishes its status to the branch `status/<vehicle>` of the desired-state
repository when it changed and at least every heartbeat (workflow/sync.py `publish`,
reconciler/core/publication.py). In any clone of that repository, after a fetch, this reads
those branches and says per vehicle which file of the repository it follows, which
revision it applied against the branch the cars follow, its apps (a car may run several:
each is named, with whether it runs), who asked for its last change (a phone, a user, the
agent), how its last pass ended, and how old its last report is — no server, no
database, nothing but refs and one small file per car. The age is measured against the
clock the caller passes in.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from reconciler.adapters import clone
from reconciler.base.errors import ConfigError, LpamError
from reconciler.base.text import columns, printable
from reconciler.core.publication import STATUS_FILE, read_status_file
from reconciler.report.fleetview import State, ago
from schemas.fleet import CarStatus
from schemas.rollout import RolloutSpec

# Imported inside functions: the document readers (~13 modules) load only when a rollout is
# read from the fleet's desired state; `lpam fleet status` without one needs none.

PREFIXES = (b"refs/remotes/origin/status/", b"refs/heads/status/")


@dataclass(frozen=True)
class Vehicle:
    vehicle: str
    follows: str | None  # vehicles/<id>.yaml or desired-state.yaml (None: not reported)
    applied: str | None
    up_to_date: bool | None  # applied == the followed branch's tip (None: unknown)
    app: str | None
    running: bool | None
    last_pass: str | None
    reason: str | None
    last_seen: str  # when the car last reported (its status commit's time)
    override: str | None = None  # a local override in force: "phone since <time>"
    apps: tuple[dict[str, Any], ...] = ()  # every installed app reported (`app` the first)
    changed_by: str | None = None  # who asked for the car's last change (None: not known)
    rollout: dict[str, Any] | None = None  # where it stands in a rollout (schemas/rollout.py)
    desired: str | None = None  # the revision it would apply (its source's tip, last seen)


def read(repo_path: Path, branch: str = "main") -> tuple[str | None, list[Vehicle]]:
    """(the followed branch's tip, one row per vehicle with a status branch)."""
    tip, files = clone.published(repo_path, branch=branch, prefixes=PREFIXES,
                           file=STATUS_FILE.encode())
    seen: dict[str, Vehicle] = {}
    for found in files:  # the first branch of a vehicle with a status in JSON counts
        if found.name in seen:
            continue
        when = datetime.fromtimestamp(found.commit_time, timezone.utc)
        try:
            status = read_status_file(found.content, where=Path(f"status/{found.name}") /
                                      STATUS_FILE)
        except ConfigError as exc:  # a damaged file, a newer lpam's: the car, and why
            seen[found.name] = Vehicle(found.name, None, None, None, None, None, None,
                                       exc.message, _seen(when))
            continue
        if status is not None:
            seen[found.name] = _row(found.name, status, tip, when)
    return tip, list(seen.values())


def rollout_at(repo_path: Path, tip: str | None) -> RolloutSpec | None:
    """The rollout the fleet's `desired-state.yaml` declares at `tip` (None: none, or a
    file that cannot be read: the cars' reports say why)."""
    from reconciler.base.loading import load
    from reconciler.core.documents import desired_document
    from reconciler.workflow.source import DEFAULT_FILE

    data = None if tip is None else clone.read_at(repo_path, tip, DEFAULT_FILE)
    if data is None:
        return None
    try:
        return desired_document(load(Path(DEFAULT_FILE),
                                     data.decode("utf-8", "replace"))).desired.rollout
    except LpamError:
        return None


def silence(repo_path: Path, tip: str | None) -> float:
    """How long a car may stay silent before it is `unknown`: the rollout's
    `silent_seconds` at `tip`, else `SILENT`."""
    rollout = rollout_at(repo_path, tip)
    return SILENT if rollout is None or rollout.silent_seconds is None else \
        rollout.silent_seconds


def _row(vehicle: str, status: CarStatus, tip: str | None, when: datetime) -> Vehicle:
    agent, app = status.agent, status.app
    last = agent.last_attempt
    applied = agent.applied_revision
    return Vehicle(
        vehicle=vehicle, follows=agent.follows, applied=applied,
        up_to_date=None if tip is None or applied is None else applied == tip,
        app=None if app is None else app.name, running=None if app is None else app.running,
        last_pass=None if last is None else last.result,
        reason=None if last is None else last.reason, last_seen=_seen(when),
        override=None if status.override is None else
        f"{status.override.by} since {status.override.since}",
        apps=tuple(a.model_dump(mode="json") for a in status.installed()),
        changed_by=None if status.last_change is None or status.last_change.by is None
        else status.last_change.by.shown,
        rollout=None if agent.rollout is None else agent.rollout.model_dump(mode="json"),
        desired=agent.desired_revision)


SILENT = 13 * 3600.0
"""Past this, a car with no report is `unknown`, when the fleet declares no rollout: twice
the default heartbeat (6 h) and an hour, so a quiet car that reports at its heartbeat is
never called unknown. A rollout's `silent_seconds` replaces it: the lab said there how long
a silence it tolerates."""


def state_of(row: Vehicle, now: datetime, *, silent: float = SILENT) -> tuple[State, str]:
    """The car's state (report/fleetview.py: confirmed, waiting, rolled back, unknown) and
    the words that say which revision, since when, which gate, why — from its report
    alone, judged at `now`."""
    seconds = age(row, now)
    if row.follows is None and row.applied is None and row.reason is not None:
        return "unknown", f"its report cannot be read: {row.reason}"
    if seconds >= silent:
        return "unknown", f"no report since {row.last_seen} ({ago(seconds)})"
    applied = (row.applied or "nothing")[:12]
    stage = (row.rollout or {}).get("stage")
    why = (row.rollout or {}).get("reason") or row.reason
    if stage == "rolled back" or row.last_pass in ("rolled back", "failed"):
        failed = (row.rollout or {}).get("revision") if stage == "rolled back" else None
        return "rolled back", f"{(failed or 'a revision')[:12]} failed: {why}; " \
            f"runs {applied}"
    if stage in ("waiting", "halted") or row.last_pass == "deferred":
        since = (row.rollout or {}).get("since")
        return "waiting", f"{why}{f' (since {since})' if since else ''}; runs {applied}"
    stopped = [str(a.get("name")) for a in row.apps if a.get("running") is False] or \
        ([row.app] if row.app and row.running is False else [])
    if stopped:
        return "waiting", f"runs {applied}, but {', '.join(stopped)} does not run: its " \
            "health is not proven"
    if stage == "proving":
        return "confirmed", f"runs {applied}, health checks passed; proving it: {why}"
    return "confirmed", f"runs {applied}, health checks passed" + \
        (", proven" if stage == "proven" else "")


YES_NO = {True: "yes", False: "no", None: "?"}


def _apps(row: Vehicle) -> str:
    """The App cell: the app, or with several installed each one's name, in order."""
    if len(row.apps) > 1:
        return ", ".join(str(a.get("name") or "?") for a in row.apps)
    return row.app or "-"


def _running(row: Vehicle) -> str:
    """The Running cell: the app's, or with several apps each one's, in the App cell's
    order (`yes, no, yes`)."""
    if len(row.apps) > 1:
        return ", ".join(YES_NO[a.get("running")] for a in row.apps)
    return YES_NO[row.running]


def _seen(when: datetime) -> str:
    return when.isoformat(timespec="seconds")


def age(row: Vehicle, now: datetime) -> float:
    """Seconds since the car's last report, by `now` (negative: the car's clock is ahead)."""
    return (now - datetime.fromisoformat(row.last_seen)).total_seconds()


def as_json(tip: str | None, rows: list[Vehicle], *, now: datetime,
            silent: float = SILENT) -> dict[str, Any]:
    found = []
    for row in rows:
        state, detail = state_of(row, now, silent=silent)
        found.append({**asdict(row), "state": state, "detail": detail,
                      "age_seconds": int(age(row, now)), "age": ago(age(row, now))})
    return {"tip": tip, "vehicles": found}


def as_table(tip: str | None, rows: list[Vehicle], *, now: datetime,
             silent: float = SILENT) -> str:
    if not rows:
        return ("No vehicle has published its status yet (no status/* branches: fetch, or "
                "check that the cars may push to this repository).")
    header = ("Vehicle", "State", "Follows", "Applied", "Current", "App", "Running",
              "Changed by", "Last pass", "Last report")
    states = [state_of(r, now, silent=silent) for r in rows]
    cells = [tuple(printable(v)[:60] for v in (
        r.vehicle, state[0], r.follows or "?", (r.applied or "none")[:12],
        YES_NO[r.up_to_date],
        _apps(r) + (f" (local override: {r.override})" if r.override else ""),
        _running(r), r.changed_by or "-",
        (r.last_pass or "-") + (f": {r.reason}" if r.reason else ""),
        ago(age(r, now)))) for r, state in zip(rows, states)]
    lines = columns(header, cells)
    lines += [f"  {printable(r.vehicle)} {state}: {printable(detail)}"
              for r, (state, detail) in zip(rows, states)]
    lines.append(f"\nThe cars follow {(tip or 'an unknown revision')[:12]}. A car reports "
                 "when its status changes and at least every\nheartbeat (agent.yaml "
                 "heartbeat_seconds, 6 h unless set): a much older report means it is off "
                 "or offline.")
    return "\n".join(lines)
