"""The update gates' decision, pure: the vehicle's motion, the locks apps hold and the time
of day in, one state per gate out, each with the reason a person reads.

Place in the flow: the gate adapter (reconciler/adapters/can/gate.py) observes and asks
here; the executor cuts over only when every gate is open (a stop at a light is not parked:
the car must have stood `stationary_seconds`). openpilot updates only with the ignition off,
balena waits for an app's update lock, Argo CD has sync windows: lpam combines the three.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from reconciler.base.text import counted
from reconciler.core.vehicle.motion import Motion
from schemas.vehicle import GatesSpec


@dataclass(frozen=True)
class GateState:
    """One gate now: `name` is vehicle, window or lock."""

    name: str
    open: bool
    detail: str

    def describe(self) -> str:
        return f"{self.name}: {'open' if self.open else 'closed'} — {self.detail}"


def decide(gates: GatesSpec, *, motion: Motion, source: str, busy: Sequence[str],
           minute: int, unit: str = "km/h") -> list[GateState]:
    """Every gate's state. `busy` describes each lock held now; `minute` is the local time
    of day in minutes after midnight."""
    return [vehicle(gates, motion, source, unit), window(gates, minute),
            *locks(gates, busy)]


def all_open(states: Sequence[GateState]) -> bool:
    return all(s.open for s in states)


def vehicle(gates: GatesSpec, motion: Motion, source: str, unit: str = "km/h") -> GateState:
    if motion.speed is None:
        allowed = gates.on_no_signal == "allow"
        return GateState("vehicle", allowed,
                         f"no signal from {source}: {motion.reason}; "
                         + ("on_no_signal: allow" if allowed else
                            "the car may be moving (on_no_signal: defer)"))
    speed = f"{motion.speed:.1f} {unit} from {source}"
    if motion.speed > gates.stationary_below:
        return GateState("vehicle", False, f"moving: {speed}")
    need = gates.stationary_seconds
    if motion.stationary_for < need:
        return GateState("vehicle", False, f"stationary for {motion.stationary_for:.0f} s of "
                         f"the {need:g} s needed (a stop is not parked): {speed}")
    return GateState("vehicle", True, f"parked: stationary for {motion.stationary_for:.0f} s "
                     f"(≥ {need:g} s): {speed}")


def window(gates: GatesSpec, minute: int) -> GateState:
    spans = gates.spans()
    if not spans:
        return GateState("window", True, "no windows: any time of day")
    now = f"{minute // 60:02d}:{minute % 60:02d}"
    inside = [w for w, span in zip(gates.windows, spans) if within(span, minute)]
    if inside:
        return GateState("window", True, f"now {now} is within {inside[0]}")
    return GateState("window", False, f"now {now} is outside {', '.join(gates.windows)}")


def within(span: tuple[int, int], minute: int) -> bool:
    """Whether `minute` lies in [start, end); a span whose end is before its start wraps
    past midnight ('22:00-06:00')."""
    start, end = span
    if start < end:
        return start <= minute < end
    return minute >= start or minute < end


def locks(gates: GatesSpec, busy: Sequence[str]) -> list[GateState]:
    if not gates.locks:
        return []
    if not busy:
        return [GateState("lock", True, f"{counted(len(gates.locks), 'lock')} free")]
    return [GateState("lock", False, text) for text in busy]
