"""Whether the vehicle stands, and since when: a pure fold over its speed samples.

Place in the flow: the gate (reconciler/adapters/can/gate.py) decodes the speed signal of
each frame its source yields and adds (time, speed) here; `motion(now)` then says what the
policy (core/vehicle/policy.py) needs. Being pure, a decision can be replayed from any recording.

Times are the source's: a libpanda CSV and socketcand stamp frames with the wall clock
(epoch seconds), as `now` is. A gap longer than `stale` between two samples breaks the
stationary run — nothing is known of the car during it — so a car is "parked" only after
`stationary_seconds` of samples that say so.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Motion:
    """The vehicle's motion as its samples show it at `now`. `speed` None: no signal
    (`reason` says why)."""

    speed: float | None
    stationary_for: float = 0.0  # seconds at or below the threshold, up to the newest sample
    age: float | None = None  # seconds since the newest sample
    reason: str | None = None


class Tracker:
    """The stationary run of a stream of speed samples (see the module docstring)."""

    def __init__(self, *, below: float, stale: float) -> None:
        self._below = below
        self._stale = stale
        self._since: float | None = None  # time of the first sample of the current standstill
        self._newest: float | None = None
        self._speed: float | None = None
        self.samples = 0

    def add(self, time: float, speed: float) -> None:
        if self._newest is not None:
            if time < self._newest:
                return  # out of order (a second reader of the same bus): already counted
            if time - self._newest > self._stale:
                self._since = None  # a gap: the standstill is only known from here on
        if speed <= self._below:
            if self._since is None:
                self._since = time
        else:
            self._since = None
        self._newest, self._speed = time, speed
        self.samples += 1

    def motion(self, now: float, *, what: str = "speed") -> Motion:
        if self._newest is None or self._speed is None:
            return Motion(None, reason=f"no {what} frame seen")
        age = max(0.0, now - self._newest)
        if age > self._stale:
            return Motion(None, age=age, reason=f"no {what} frame for {_seconds(age)} "
                          f"(stale after {_seconds(self._stale)})")
        standing = 0.0 if self._since is None else self._newest - self._since
        return Motion(self._speed, stationary_for=standing, age=age)


def _seconds(value: float) -> str:
    if value >= 86400 * 2:
        return f"{value / 86400:.0f} days"
    return f"{value:.0f} s" if value >= 10 else f"{value:.1f} s"
