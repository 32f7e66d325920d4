"""`lpam fleet report`: the fleet at a glance, as a static page built in a clone of the
fleet repository from what the cars published — no server, no network, nothing but the
status branches (issue 34).

What a car published gives its row: its state (workflow/fleet.py `state_of`, the same
words `lpam fleet status` prints), revision, apps, the gate or wave it waits for, a local
override, the age of its report. Its timeline is what ran, from the provenance timeline it
publishes beside its status (`timeline.json`), else from its status alone (what it runs
since its last change); its last passes add the deferrals, waits and rollbacks. Gathering
is here, drawing in report/fleetpage.py: each is tested alone.
"""

from __future__ import annotations

from collections import Counter
from datetime import datetime, timedelta
from pathlib import Path

from reconciler.adapters import clone
from reconciler.base.atomic import write_atomic
from reconciler.base.errors import LpamError
from reconciler.core.provenance import utc
from reconciler.core.publication import STATUS_FILE, read_status_file
from reconciler.report.fleetview import CarView, FleetView, Mark, RevisionSummary
from reconciler.workflow import fleet
from reconciler.workflow.provenance import TIMELINE_FILE, known_published
from schemas.fleet import CarStatus

# Imported inside functions: the page's drawing loads only when a page is written.

DAYS = 30
"""How far back the timelines reach."""

PREFIXES = (b"refs/remotes/origin/status/", b"refs/heads/status/")


def gather(repo_path: Path, *, branch: str = "main", now: datetime,
           days: int = DAYS) -> FleetView:
    """The fleet as its clone at `repo_path` shows it, judged at `now`."""
    tip, rows = fleet.read(repo_path, branch)
    silent = fleet.silence(repo_path, tip)
    since = now - timedelta(days=days)
    timelines = {f.name: f.content for f in reversed(clone.published(
        repo_path, branch=branch, prefixes=PREFIXES, file=TIMELINE_FILE.encode())[1])}
    statuses = {f.name: f.content for f in reversed(clone.published(
        repo_path, branch=branch, prefixes=PREFIXES, file=STATUS_FILE.encode())[1])}
    cars = []
    wanted: dict[str, str] = {}
    for row in sorted(rows, key=lambda r: r.vehicle):
        state, detail = fleet.state_of(row, now, silent=silent)
        status = _status(statuses.get(row.vehicle), row.vehicle)
        wanted[row.vehicle] = row.desired or tip or "?"
        marks = _ran(timelines.get(row.vehicle), status, since) + _passes(status)
        cars.append(CarView(
            vehicle=row.vehicle, state=state, detail=detail, revision=row.applied,
            apps=tuple(f"{a.get('name')} ({_running(a.get('running'))})" for a in row.apps)
            or ((f"{row.app} ({_running(row.running)})",) if row.app else ()),
            gate=_waits_for(row) if state == "waiting" else None, override=row.override,
            reported=datetime.fromisoformat(row.last_seen),
            marks=tuple(sorted((m for m in marks if (m.end or now) >= since),
                               key=lambda m: m.start))))
    return FleetView(generated=now, tip=tip, cars=tuple(cars),
                     revisions=_summary(cars, wanted), rollout=_rollout(repo_path, tip),
                     since=since)


def write_report(repo_path: Path, out: Path, *, branch: str = "main",
                 now: datetime) -> Path:
    """Write `out/index.html`; its path."""
    from reconciler.report.fleetpage import render

    page = out / "index.html"
    write_atomic(page, render(gather(repo_path, branch=branch, now=now)))
    return page


def _waits_for(row: fleet.Vehicle) -> str:
    """What a waiting car waits for, in a few words (its row's "why" says the rest)."""
    rollout, reason = row.rollout or {}, row.reason or ""
    if rollout.get("stage") == "halted":
        return "a halted rollout: a new revision or a revert"
    if rollout.get("stage") == "waiting" and "waits for wave" in reason:
        return f"its wave's turn (wave {rollout.get('wave')})"
    if rollout.get("stage") == "waiting" and "no wave" in reason:
        return "a wave that names it"
    if row.last_pass == "deferred":
        return "an update gate"
    return "its apps to run"


def _summary(cars: list[CarView], wanted: dict[str, str]) -> tuple[RevisionSummary, ...]:
    counts: dict[str, Counter[str]] = {}
    for car in cars:
        counts.setdefault(wanted[car.vehicle], Counter())[car.state] += 1
    return tuple(RevisionSummary(revision, c["confirmed"], c["waiting"], c["rolled back"],
                                 c["unknown"]) for revision, c in counts.items())


def _ran(content: bytes | None, status: CarStatus | None, since: datetime) -> list[Mark]:
    """What ran: the published timeline's intervals (a power cut's end is uncertain and
    says so), else — a car whose lpam publishes no timeline — what its status says runs,
    since its last change."""
    if content is not None:
        try:
            known = known_published(content)
        except ValueError:
            known = None
        if known is not None:
            marks = []
            for interval in known.found:
                end = None if interval.ended is None else interval.ended.latest
                if end is not None and end < since:
                    continue
                uncertain = interval.ended is not None and \
                    interval.ended.certainty == "uncertain"
                label = f"{interval.app}@{interval.generation[:12]}" + (
                    f", ended {interval.ended_how}" if interval.ended_how else "") + (
                    " (its end uncertain: power lost)" if uncertain else "")
                marks.append(Mark(interval.began.earliest, end, "ran", label))
                if interval.ended_how == "rollback":
                    assert end is not None
                    marks.append(Mark(end, end, "rollback", f"{interval.app} rolled back"))
            return marks
    return [] if status is None else _from_status(status, since)


def _from_status(status: CarStatus, since: datetime) -> list[Mark]:
    """What runs by the status alone: each installed app from the car's last change (its
    start unknown without one: drawn from the report's start, and said so)."""
    change = status.last_change
    start = since if change is None else max(utc(datetime.fromisoformat(change.time)), since)
    known = "" if change is not None else ", running before this report's start or since " \
        "a time its status does not say"
    return [Mark(start, None, "ran", f"{app.name}@{(app.generation or '?')[:12]} (from its "
                 f"status: it publishes no timeline{known})")
            for app in status.installed() if app.running]


def _status(content: bytes | None, vehicle: str) -> CarStatus | None:
    """The car's published status (None: none, or damaged: its row says so already)."""
    if content is None:
        return None
    try:
        return read_status_file(content, where=Path("status", vehicle, STATUS_FILE))
    except LpamError:
        return None


def _passes(status: CarStatus | None) -> list[Mark]:
    """The car's last passes that were not a plain success: deferrals (a gate, a wave),
    rollbacks and failures, as instants."""
    if status is None:
        return []
    marks = []
    for attempt in status.agent.passes:
        kind = {"deferred": "deferral", "rolled back": "rollback", "failed": "rollback"
                }.get(attempt.result)
        if kind is None:
            continue
        at = datetime.fromisoformat(attempt.time)
        marks.append(Mark(at, at, "deferral" if kind == "deferral" else "rollback",
                          f"{attempt.result}: {attempt.reason or ''}".strip(": ")))
    return marks


def _rollout(repo_path: Path, tip: str | None) -> str | None:
    spec = fleet.rollout_at(repo_path, tip)
    if spec is None:
        return None
    waves = " → ".join(", ".join(w) for w in spec.waves)
    silent = "a silent car holds the waves after it" if spec.silent_seconds is None else \
        f"a car silent for {spec.silent_seconds:g} s is skipped"
    return f"waves {waves}; each proves a revision for {spec.prove_seconds:g} s; {silent}"


def _running(value: object) -> str:
    return "running" if value is True else "stopped" if value is False else "?"

