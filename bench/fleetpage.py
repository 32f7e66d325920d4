"""How long the fleet page takes to build for a big fleet, and how large it is.

    python -m bench.fleetpage --cars 100 --days 30

A synthetic fleet (deterministic): each car switches its controller one to three times a
day, a few passes a day wait for a gate, now and then one rolls back, and a few cars have
been silent for a day. Times `render` (report/fleetpage.py) alone, and the whole
`lpam fleet report` gathering from a real clone is measured by tests and the field trial,
not here: what grows with the fleet is the drawing.
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
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

NOW = datetime(2026, 11, 28, 6, 0, tzinfo=timezone.utc)


def synthetic(cars: int, days: int, seed: int = 34) -> FleetView:
    """`cars` cars with `days` days of history each."""
    pick = random.Random(seed)
    since = NOW - timedelta(days=days)
    views = []
    for number in range(1, cars + 1):
        marks: list[Mark] = []
        moment = since
        while moment < NOW:
            step = timedelta(hours=pick.uniform(8, 24))
            end = min(moment + step, NOW)
            app = pick.choice(("ctl-a", "ctl-b", "pandarecord"))
            marks.append(Mark(moment, None if end == NOW else end, "ran",
                              f"{app}@{pick.getrandbits(48):012x}"))
            for _ in range(pick.randint(0, 3)):
                at = moment + (end - moment) * pick.random()
                marks.append(Mark(at, at, "deferral", "deferred: the car moves (14 km/h)"))
            if pick.random() < 0.03:
                marks.append(Mark(end, end, "rollback", "rolled back: health check failed"))
            moment = end
        state: State = pick.choices(STATES, weights=(80, 12, 4, 4))[0]
        views.append(CarView(
            vehicle=f"car-{number:03d}", state=state, detail=f"{state}: synthetic",
            revision=f"{pick.getrandbits(160):040x}", apps=("ctl-a (running)",),
            gate="the car moves" if state == "waiting" else None, override=None,
            reported=NOW - timedelta(minutes=pick.randint(1, 2000)),
            marks=tuple(sorted(marks, key=lambda m: m.start))))
    counts = {s: sum(1 for v in views if v.state == s) for s in STATES}
    summary = RevisionSummary("c" * 40, counts["confirmed"], counts["waiting"],
                              counts["rolled back"], counts["unknown"])
    return FleetView(generated=NOW, tip="c" * 40, cars=tuple(views), revisions=(summary,),
                     rollout="waves car-001 → car-002, car-003 → *", since=since)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cars", type=int, default=100)
    parser.add_argument("--days", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=9)
    args = parser.parse_args(argv)
    view = synthetic(args.cars, args.days)
    marks = sum(len(c.marks) for c in view.cars)
    times = []
    for _ in range(args.rounds):
        began = time.perf_counter()
        page = render(view)
        times.append(time.perf_counter() - began)
    print(f"| fleet page: {args.cars} cars x {args.days} days ({marks} marks) | median of "
          f"{args.rounds} | page size |\n|---|---:|---:|")
    print(f"| render | {statistics.median(times) * 1000:.1f} ms | "
          f"{len(page.encode()) / 1024:.0f} KiB |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
