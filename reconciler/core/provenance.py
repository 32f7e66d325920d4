"""What ran on a car when, and how sure the times are: the timeline's edges read back.

Place in the flow: lpam appends `Edge`s to a car's timeline (schemas/timeline.py) as it
starts, stops and sees apps restarted; a researcher asks which app generation ran while a
CAN log was recorded. This module derives the answer from the edges alone — pure, no I/O,
no clock of its own — so that the intervals can never say more than the lines do.

Times. A Pi has no real-time clock: until GPS or NTP sets it, its wall clock is the last
shutdown's, often hours off. Within one boot, wall - boottime (`offset`) is constant
unless the clock was set, so the boot's latest stamp by boottime (not the last line that
names the boot: a power-lost line's `since` may name a moment before GPS set the clock)
gives the boot's best offset, its *reference*, and every stamp whose offset differs from
it by more than `TOLERANCE` is mapped onto it (`corrected`); the others keep the car's
wall clock (`recorded`). A time only known to lie in a window is `uncertain`.

Intervals, the rules decided here:

- `began` opens an interval for its app; `ended` for the same app (and generation, when
  the line names one) closes it; `restarted` notes a restart of the open interval of its
  boot; `clock` lines are only stamps.
- An app runs one generation at a time. A `began` for an app whose interval is still open
  in the same boot (the ended line was lost: cutover stops the old one before it starts
  the new one) closes the old one as `superseded`: it ended at the latest when the new
  one began and at the earliest when it was last seen (its began or last restart); the
  best estimate is the new began, since a cutover is short. A began of the generation
  already open is read the same way (it was started again: it had stopped unseen).
- An interval of an earlier boot ends with that boot (`power-lost`): between `since` and
  `at` when lpam wrote the line; when lpam has not (yet) written it, between its boot's
  last stamp and the next boot's first (so too for an ended line without `since` written
  in a later boot: lpam found it stopped, not when it stopped).
- An `ended` or `restarted` with nothing open to match is a lost line: ignored.

Queries treat an interval as half-open, [began, ended): at the instant of a cutover the new
generation runs, not the old one. They are conservative: an interval *may* have run at t
when its began's earliest is at or before t and its end's latest is after t.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from typing import Literal

from schemas.timeline import Edge, Stamp

TOLERANCE = 2.0
"""Seconds of offset difference within a boot taken as the same clock (stamps are taken
with whole-second care at best; a setting of the clock by GPS is minutes to hours)."""

LOST = "power-lost"
SUPERSEDED = "superseded"

Certainty = Literal["recorded", "corrected", "uncertain"]


@dataclass(frozen=True)
class Moment:
    """A time with its certainty: `recorded` is the car's clock, not known wrong;
    `corrected` is mapped onto a later setting of the clock in the same boot; `uncertain`
    is only known to lie in [earliest, latest] (`when` is the best estimate)."""

    when: datetime
    earliest: datetime
    latest: datetime
    certainty: Certainty


@dataclass(frozen=True)
class Interval:
    """One app generation running, from `began` to `ended` (None: still running as of the
    timeline's last edge), with the restarts its service manager made within it."""

    app: str
    generation: str
    software: str | None
    began: Moment
    began_how: str
    ended: Moment | None
    ended_how: str | None
    restarts: tuple[Moment, ...] = ()


def utc(moment: datetime) -> datetime:
    """`moment` as an aware UTC datetime; a naive one is taken to be UTC already (lpam
    writes UTC), never the local time of the machine reading the timeline."""
    if moment.tzinfo is None:
        return moment.replace(tzinfo=timezone.utc)
    return moment.astimezone(timezone.utc)


def _offset(stamp: Stamp) -> float:
    # Stamp.offset would read a naive wall clock as local time.
    return utc(stamp.wall).timestamp() - stamp.mono


@dataclass(frozen=True)
class _Boot:
    reference: float
    first: Stamp
    last: Stamp


def _stamps(edges: Sequence[Edge]) -> Iterator[Stamp]:
    """Every stamp the timeline holds, in file order: a line's `since` (of an earlier
    boot) before its `at`, so that boots are met in the order they happened."""
    for edge in edges:
        if edge.since is not None:
            yield edge.since
        yield edge.at


def _boots(edges: Sequence[Edge]) -> dict[str, _Boot]:
    """Each boot's first and last stamp by boottime, in order of first appearance. The
    last one (a tie goes to the later line) carries the boot's latest setting of the clock:
    its offset is the reference."""
    first: dict[str, Stamp] = {}
    last: dict[str, Stamp] = {}
    for stamp in _stamps(edges):
        if stamp.boot not in first or stamp.mono < first[stamp.boot].mono:
            first[stamp.boot] = stamp
        if stamp.boot not in last or stamp.mono >= last[stamp.boot].mono:
            last[stamp.boot] = stamp
    return {boot: _Boot(_offset(last[boot]), first[boot], last[boot]) for boot in first}


def _moment(stamp: Stamp, boots: dict[str, _Boot]) -> Moment:
    wall = utc(stamp.wall)
    boot = boots.get(stamp.boot)
    shift = 0.0 if boot is None else boot.reference - _offset(stamp)
    if abs(shift) <= TOLERANCE:
        return Moment(wall, wall, wall, "recorded")
    when = wall + timedelta(seconds=shift)
    return Moment(when, when, when, "corrected")


def _window(earliest: Moment, latest: Moment, *, when: datetime | None = None) -> Moment:
    """An uncertain moment between two known ones (in either order: corrected clocks of
    two boots may disagree), best estimated by `when` or else the earliest."""
    low = min(earliest.earliest, latest.earliest)
    high = max(earliest.latest, latest.latest)
    best = low if when is None else min(max(when, low), high)
    return Moment(best, low, high, "uncertain")


def moments(edges: Sequence[Edge]) -> list[Moment]:
    """Each edge's time (its `at`), corrected within its boot; same order as `edges`."""
    boots = _boots(edges)
    return [_moment(edge.at, boots) for edge in edges]


@dataclass
class _Open:
    """An interval still open while the edges are read."""

    order: int
    app: str
    generation: str
    software: str | None
    began: Moment
    began_how: str
    boot: str
    seen: Moment
    restarts: list[Moment] = field(default_factory=list)

    def close(self, ended: Moment | None, how: str | None) -> tuple[int, Interval]:
        return self.order, Interval(self.app, self.generation, self.software, self.began,
                                    self.began_how, ended, how, tuple(self.restarts))


def _fits(interval: _Open, edge: Edge, boot: str | None) -> bool:
    return edge.generation in (None, interval.generation) and boot in (None, interval.boot)


class _Reading:
    """The edges read in file order: what is open (by app), what an earlier boot left
    open and a later boot superseded before lpam wrote its end, and what is closed."""

    def __init__(self, edges: Sequence[Edge]) -> None:
        self.boots = _boots(edges)
        self.order = list(self.boots)
        self.open: dict[str, _Open] = {}
        self.lost: dict[tuple[str, str], _Open] = {}
        self.done: list[tuple[int, Interval]] = []

    def moment(self, stamp: Stamp) -> Moment:
        return _moment(stamp, self.boots)

    def boot_end(self, boot: str) -> Moment | None:
        """When a boot ended, as a window: after its last stamp, before the next boot's
        first (None: no later boot in the timeline, it may still run)."""
        at = self.order.index(boot)
        if at + 1 >= len(self.order):
            return None
        following = self.boots[self.order[at + 1]]
        return _window(self.moment(self.boots[boot].last), self.moment(following.first))

    def began(self, index: int, edge: Edge, app: str, generation: str) -> None:
        start = self.moment(edge.at)
        old = self.open.pop(app, None)
        if old is not None and old.boot == edge.at.boot:
            self.done.append(old.close(_window(old.seen, start, when=start.when), SUPERSEDED))
        elif old is not None:
            self.park(old)
        self.open[app] = _Open(index, app, generation, edge.software, start, edge.how,
                               edge.at.boot, start)

    def park(self, old: _Open) -> None:
        """Keep an interval of an earlier boot until its `power-lost` line comes."""
        earlier = self.lost.pop((old.app, old.generation), None)
        if earlier is not None:
            self.done.append(earlier.close(self.boot_end(earlier.boot), LOST))
        self.lost[(old.app, old.generation)] = old

    def matching(self, edge: Edge, app: str) -> _Open | None:
        """The interval an ended line closes: the app's open one, or one an earlier boot
        left (a power-lost line written after the app began again); a line with `since`
        closes only an interval of the boot it names."""
        boot = None if edge.since is None else edge.since.boot
        current = self.open.get(app)
        if current is not None and _fits(current, edge, boot):
            return self.open.pop(app)
        for key, left in list(self.lost.items()):
            if key[0] == app and _fits(left, edge, boot):
                return self.lost.pop(key)
        return None

    def ended(self, edge: Edge, app: str) -> None:
        found = self.matching(edge, app)
        if found is None:
            return  # a lost began line: nothing to close
        if edge.since is not None:
            end = _window(self.moment(edge.since), self.moment(edge.at))
            self.done.append(found.close(end, edge.how))
        elif edge.at.boot != found.boot:
            self.done.append(found.close(self.boot_end(found.boot), LOST))
        else:
            self.done.append(found.close(self.moment(edge.at), edge.how))

    def restarted(self, edge: Edge, app: str) -> None:
        current = self.open.get(app)
        if current is None or current.boot != edge.at.boot:
            return  # a lost began line, or a restart the interval's boot did not see
        if edge.generation in (None, current.generation):
            restart = self.moment(edge.at)
            current.restarts.append(restart)
            current.seen = restart

    def finish(self) -> list[Interval]:
        """The closed intervals and the open ones, in the order they began; one still open
        in an earlier boot ended with it."""
        for left in [*self.lost.values(), *self.open.values()]:
            end = self.boot_end(left.boot)
            self.done.append(left.close(end, None if end is None else LOST))
        return [interval for _, interval in sorted(self.done, key=lambda pair: pair[0])]


def intervals(edges: Sequence[Edge]) -> list[Interval]:
    """What ran when: one interval per run of an app generation, in the order they began."""
    reading = _Reading(edges)
    for index, edge in enumerate(edges):
        app = edge.app
        if app is None or edge.kind == "clock":
            continue
        if edge.kind == "began" and edge.generation is not None:
            reading.began(index, edge, app, edge.generation)
        elif edge.kind == "ended":
            reading.ended(edge, app)
        elif edge.kind == "restarted":
            reading.restarted(edge, app)
    return reading.finish()


def may_run(interval: Interval, start: datetime, end: datetime) -> bool:
    """Whether `interval` may have run at some instant of [start, end]: it began at the
    earliest by `end` and ended at the latest after `start`."""
    if interval.began.earliest > end:
        return False
    return interval.ended is None or interval.ended.latest > start


def overlapping(found: Sequence[Interval], start: datetime, end: datetime) -> list[Interval]:
    """The intervals that may have run at any instant of [start, end] (naive: UTC; the
    bounds in either order), in their order."""
    low, high = sorted((utc(start), utc(end)))
    return [interval for interval in found if may_run(interval, low, high)]


def at(found: Sequence[Interval], when: datetime) -> list[Interval]:
    """The intervals that may have been running at the instant `when`."""
    return overlapping(found, when, when)
