"""What the fleet page shows (`lpam fleet report`), as plain data: gathered from the cars'
published statuses and timelines by workflow/fleet.py, drawn by report/fleetpage.py.

It stands apart from both so that the page is drawn from data alone (a test or a benchmark
builds a view of a hundred cars without a repository) and the gathering is tested without
reading HTML.

The four states a car is in, as a lab manager at 6 am asks them:

- `confirmed`: it runs the revision it applied, its health proven (its last pass converged
  and its apps run);
- `waiting`: a revision is staged and waits — for an update gate (the car moves), for its
  wave's turn, or for a halted rollout;
- `rolled back`: its last attempt failed or was rolled back, and it runs what it ran before;
- `unknown`: no report for longer than the fleet expects, or a report lpam cannot read.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Literal

State = Literal["confirmed", "waiting", "rolled back", "unknown"]
STATES: tuple[State, ...] = ("confirmed", "waiting", "rolled back", "unknown")

MarkKind = Literal["ran", "rollback", "deferral", "wait", "unknown"]


@dataclass(frozen=True)
class Mark:
    """One thing on a car's timeline: what ran over an interval (`end` None: still runs at
    the report's end), or an instant (`start` == `end`): a rollback, a deferral."""

    start: datetime
    end: datetime | None
    kind: MarkKind
    label: str  # shown as text: `app@generation`, a reason


@dataclass(frozen=True)
class CarView:
    vehicle: str
    state: State
    detail: str  # the state in words: which revision, since when, which gate, why
    revision: str | None  # the fleet revision it applied (None: none yet)
    apps: tuple[str, ...]  # each installed app as `name (running)` / `name (stopped)`
    gate: str | None  # the gate or wave it waits for, when it waits
    override: str | None  # a local override in force: "phone since <time>"
    reported: datetime | None  # its last report (None: never, or unreadable)
    marks: tuple[Mark, ...]  # its timeline, oldest first


@dataclass(frozen=True)
class RevisionSummary:
    """How many cars stand where for one desired revision (the cars whose last report
    names it as the revision they would apply)."""

    revision: str
    confirmed: int
    waiting: int
    failed: int
    unknown: int


@dataclass(frozen=True)
class FleetView:
    generated: datetime  # when the report was built (the caller's clock)
    tip: str | None  # the revision the cars follow
    cars: tuple[CarView, ...]
    revisions: tuple[RevisionSummary, ...]
    rollout: str | None  # the rollout in force, in words (None: none declared)
    since: datetime  # the timelines' start (the report's end is `generated`)


def ago(seconds: float) -> str:
    """An age as people say it: "45 s ago", "12 min ago", "3 h ago", "4 d ago"."""
    if seconds < -60:
        return f"{ago(-seconds).removesuffix(' ago')} ahead (the car's clock)"
    seconds = max(seconds, 0)
    for unit, size, below in (("s", 1, 60), ("min", 60, 3600), ("h", 3600, 48 * 3600)):
        if seconds < below:
            return f"{int(seconds // size)} {unit} ago"
    return f"{int(seconds // 86400)} d ago"
