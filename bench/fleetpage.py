"""The fleet page's cost (report/fleetpage.py): how long `render` takes for a fleet over a
month, and how large the page is.

The view is synthetic and deterministic (`synthetic`, also the browser test's page): each
car runs a recorder the whole window and a controller that switches one to three times a
day; now and then an update is deferred by a gate, waits for its wave, is rolled back, or
flaps (ten runs of two minutes: the narrow marks the page merges); a car may go unheard
for a night. Reports every five minutes would be no mark at all: a mark is a change.

    .venv/bin/python -m bench.fleetpage [--cars 100] [--days 30] [--rounds 20] [--seed 1]

Prints the median render time of `--rounds` rounds and the page's size.
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from datetime import datetime, timedelta, timezone

from reconciler.report.fleetpage import render
from reconciler.report.fleetview import (
    STATES,
    CarView,
    FleetView,
    Mark,
    RevisionSummary,
    State,
)

GENERATED = datetime(2026, 11, 20, 6, 0, tzinfo=timezone.utc)
DETAILS: dict[State, str] = {
    "confirmed": "runs {rev} since {when}, health proven",
    "waiting": "{rev} staged, waits for the gate parked-and-charging",
    "rolled back": "{rev} failed its health check (controller exited 1); runs the one before",
    "unknown": "no report since {when}"}


def synthetic(cars: int, days: int, seed: int = 1) -> FleetView:
    """`cars` cars over `days` days, the same for the same arguments; the first four cars
    are in the four states, in order."""
    rng = random.Random(seed)
    since = GENERATED - timedelta(days=days)
    tip, before = f"{rng.getrandbits(160):040x}", f"{rng.getrandbits(160):040x}"
    views = []
    tally: dict[str, dict[State, int]] = {tip: dict.fromkeys(STATES, 0),
                                         before: dict.fromkeys(STATES, 0)}
    for number in range(cars):
        state: State = STATES[number] if number < len(STATES) else \
            rng.choices(STATES, weights=(70, 15, 8, 7))[0]  # each state in a small fleet
        desired = tip if rng.random() < 0.8 else before
        tally[desired][state] += 1
        marks = _marks(rng, since, days)
        if state == "rolled back":  # its last attempt, a few hours ago
            back = GENERATED - timedelta(hours=rng.uniform(1, 12))
            marks.append(Mark(back, back, "rollback", "controller exited 1 during its health "
                                                      "check"))
            marks.sort(key=lambda m: m.start)  # oldest first, as a view has them
        reported = None if state == "unknown" and rng.random() < 0.3 else \
            GENERATED - timedelta(minutes=rng.randint(1, 3000 if state == "unknown" else 20))
        when = (reported or since).strftime("%Y-%m-%d %H:%M UTC")
        views.append(CarView(
            vehicle=f"car-{number:03d}", state=state,
            detail=DETAILS[state].format(rev=desired[:12], when=when),
            revision=None if reported is None else (before if state != "confirmed"
                                                    else desired),
            apps=("recorder (running)", "controller (running)" if state != "rolled back"
                  else "controller (stopped)"),
            gate="parked-and-charging" if state == "waiting" else None,
            override=f"phone since {when}" if rng.random() < 0.05 else None,
            reported=reported, marks=tuple(marks)))
    revisions = tuple(RevisionSummary(revision=rev, confirmed=t["confirmed"],
                                      waiting=t["waiting"], failed=t["rolled back"],
                                      unknown=t["unknown"]) for rev, t in tally.items())
    return FleetView(generated=GENERATED, tip=tip, cars=tuple(views), revisions=revisions,
                     rollout="waves: canary (3 cars), then 20%, then all; wave 2 of 3",
                     since=since)


def _marks(rng: random.Random, since: datetime, days: int) -> list[Mark]:
    marks = [Mark(since, None, "ran", "recorder@rec-001")]
    start, generation = since, 0
    for day in range(days):
        if rng.random() < 0.1:  # unheard for a night
            night = since + timedelta(days=day, hours=22)
            marks.append(Mark(night, night + timedelta(hours=8), "unknown",
                              "no report for 8 h"))
        for _ in range(rng.choice((1, 1, 2, 3))):
            at = since + timedelta(days=day, hours=rng.uniform(6, 20))
            if at <= start:
                continue
            if rng.random() < 0.15:
                marks.append(Mark(at, at, "deferral", "gate moving: the car drives (12 km/h)"))
                continue
            if rng.random() < 0.05:
                marks.append(Mark(at, at + timedelta(minutes=40), "wait",
                                  "waits for wave 2"))
            label = f"controller@ctl-{generation:03d}"
            if rng.random() < 0.03:  # flaps, then is rolled back
                marks.append(Mark(start, at, "ran", label))
                for n in range(10):
                    flap = at + timedelta(minutes=2 * n)
                    marks.append(Mark(flap, flap + timedelta(minutes=2), "ran",
                                      f"controller@ctl-{generation + 1:03d}"))
                start = at + timedelta(minutes=20)
                marks.append(Mark(start, start, "rollback",
                                  f"ctl-{generation + 1:03d} exited 1 ten times"))
                continue
            marks.append(Mark(start, at, "ran", label))
            start, generation = at, generation + 1
    marks.append(Mark(start, None, "ran", f"controller@ctl-{generation:03d}"))
    return sorted(marks, key=lambda m: m.start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cars", type=int, default=100)
    parser.add_argument("--days", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    view = synthetic(args.cars, args.days, args.seed)
    times = []
    for _ in range(args.rounds):
        clock = time.perf_counter()
        page = render(view)
        times.append(time.perf_counter() - clock)
    marks = sum(len(c.marks) for c in view.cars)
    size = len(page.encode())
    print(f"{args.cars} cars x {args.days} days: {marks} marks "
          f"({marks / max(args.cars, 1):.0f} a car), {page.count('data-kind=')} drawn")
    print(f"render: median {statistics.median(times) * 1000:.1f} ms of {args.rounds} rounds "
          f"(min {min(times) * 1000:.1f}, max {max(times) * 1000:.1f})")
    print(f"page: {size} bytes ({size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
