"""The update gates, observed: the vehicle's speed from its CAN source, the apps' update
locks, the local time of day — decided by the pure policy (reconciler/core/vehicle/policy.py).

Place in the flow: the executor asks `hold` just before the first cutover step (the `Gate`
port, engine/execution/ports.py); `lpam gates` asks `states`. Preparation (fetch, dependencies,
builds) never waits on a gate: only the swap of the running app does.

How the speed is known: a recording (a libpanda CSV followed as it grows, a log) has
history, so the last `stationary_seconds` are read back from its end and the answer is
immediate; a live bus has none, so the stationary time is what lpam has heard itself
(`--wait` at least `stationary_seconds`). While waiting, new frames are read as they come
(the source sleeps between reads: this runs beside the experiment on a Pi). A source that
cannot be opened or read, a DBC that cannot be read, frames too short for the signal: all
"no signal", with the reason, which `on_no_signal` turns into closed (defer) or open.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.adapters.can.dbc import speed_definition
from reconciler.base.errors import ConfigError, Deferred, VehicleSourceError
from reconciler.base.layout import Layout
from reconciler.core.vehicle.motion import Motion, Tracker
from reconciler.core.vehicle.policy import GateState, all_open, decide
from schemas.vehicle import GatesSpec, VehicleSpec

if TYPE_CHECKING:
    from reconciler.adapters.can.sources import FrameSource
    from reconciler.adapters.locks import UpdateLocks
    from reconciler.core.vehicle.signal import SignalDef

# Imported inside functions: the vehicle source (python-can: optional, on a car) loads only when
# a gate is read; locks and signal decoding are cheap (1-2 modules) and follow that use.

LISTEN_SLICE = 1.0  # seconds of frames read between two decisions while waiting
FIRST_LISTEN = 3.0  # a live bus is heard this long (at most stale_seconds) to know the speed
PROGRESS_EVERY = 10.0


def local_minute() -> int:
    now = datetime.now().astimezone()
    return now.hour * 60 + now.minute


@dataclass
class VehicleGate:
    """The gates of one desired state (`gates:` and `vehicle:`), paths taken under
    `layout`'s root; relative source and DBC paths are relative to the desired state's
    folder."""

    gates: GatesSpec
    vehicle: VehicleSpec
    layout: Layout
    base_dir: Path
    clock: Callable[[], float] = time.time  # the sources' clock: epoch seconds
    monotonic: Callable[[], float] = time.monotonic
    minute: Callable[[], int] = local_minute

    @property
    def unclaimed_free(self) -> bool:
        return self.gates.unclaimed == "free"

    def states(self) -> list[GateState]:
        from reconciler.adapters.locks import probe

        with self._watch() as watch:
            busy = [b.describe() for b in probe(self._lock_specs())]
            return watch.decide(busy)

    def hold(self, *, wait: float, progress: Callable[[str], None]) -> _Locks:
        from reconciler.adapters.locks import UpdateLocks

        deadline = self.monotonic() + max(0.0, wait)
        said = self.monotonic()
        with self._watch() as watch:
            while True:
                locks = UpdateLocks()
                busy = [b.describe() for b in locks.take(self._lock_specs())]
                states = watch.decide(busy)
                if all_open(states):
                    return _Locks(locks)  # held through the cutover
                locks.release()
                now = self.monotonic()
                closed = "; ".join(s.describe() for s in states if not s.open)
                if now >= deadline:
                    raise Deferred(
                        "the update gates are closed: " + closed,
                        hint="everything is prepared and the running app is untouched; "
                        "the next apply or agent pass tries again (`--wait SECONDS` waits "
                        "for the gates, `lpam gates` shows them)",
                        gates=tuple(s.name for s in states if not s.open))
                if now - said >= PROGRESS_EVERY:
                    said = now
                    progress("waiting for the gates: " + closed)
                watch.listen(min(deadline, now + LISTEN_SLICE))

    def _lock_specs(self) -> list[tuple[Path, bool]]:
        return [(self.layout.under(lock.path), lock.persistent) for lock in self.gates.locks]

    @contextmanager
    def _watch(self) -> Iterator[_Watch]:
        """The vehicle's source opened, what it already holds read (`_Watch.start`)."""
        watch = _Watch(self)
        try:
            watch.start()
            yield watch
        finally:
            watch.close()


class _Watch:
    """One source opened for one decision or one wait: its backlog read, then new frames
    as they come, each speed frame folded into a Tracker."""

    def __init__(self, gate: VehicleGate) -> None:
        self._gate = gate
        vehicle = gate.vehicle
        self._tracker = Tracker(below=gate.gates.stationary_below,
                                stale=vehicle.stale_seconds)
        self._source: FrameSource | None = None
        self._signal: SignalDef | None = None
        self._problem: str | None = None
        self._short = 0
        self.description = _describe(vehicle)
        try:
            self._signal = speed_definition(vehicle.speed, gate.base_dir)
            self._source = open_vehicle_source(gate.vehicle, layout=gate.layout,
                                               base_dir=gate.base_dir,
                                               ids=[self._signal.frame_id])
            self.description = self._source.description
        except (VehicleSourceError, ConfigError) as exc:
            self._problem = exc.message

    def start(self) -> None:
        """Read what the source already holds; a live bus, which holds nothing, is heard
        until its first speed frame (at most FIRST_LISTEN or stale_seconds)."""
        if self._source is None:
            return
        gates, vehicle = self._gate.gates, self._gate.vehicle
        try:
            self._feed(self._source.backlog(gates.stationary_seconds + vehicle.stale_seconds))
        except VehicleSourceError as exc:  # the recording cannot be read: no signal, why
            self._problem = exc.message
            return
        if vehicle.source.bus is not None:
            listen = min(FIRST_LISTEN, vehicle.stale_seconds)
            self.listen(self._gate.monotonic() + listen, until_speed=True)

    def listen(self, deadline: float, *, until_speed: bool = False) -> None:
        if self._source is None:
            time.sleep(max(0.0, min(deadline - self._gate.monotonic(), LISTEN_SLICE)))
            return
        seen = self._tracker.samples
        for message in self._source.frames(deadline):
            self._feed((message,))
            if until_speed and self._tracker.samples > seen:
                return

    def decide(self, busy: Sequence[str]) -> list[GateState]:
        return decide(self._gate.gates, motion=self.motion(), source=self.description,
                      busy=busy, minute=self._gate.minute())

    def motion(self) -> Motion:
        if self._problem is not None:
            return Motion(None, reason=self._problem)
        signal = self._signal
        what = f"speed (id 0x{signal.frame_id:X})" if signal is not None else "speed"
        found = self._tracker.motion(self._gate.clock(), what=what)
        if found.speed is None and self._short and self._tracker.samples == 0:
            return Motion(None, reason=f"{self._short} frame(s) of id 0x"
                          f"{signal.frame_id if signal else 0:X} too short for the signal")
        return found

    def _feed(self, messages: Sequence[object] | Iterator[object]) -> None:
        from reconciler.core.vehicle.signal import decode

        signal = self._signal
        if signal is None:
            return
        for message in messages:
            if getattr(message, "arbitration_id", None) != signal.frame_id:
                continue
            value = decode(signal, bytes(getattr(message, "data", b"")))
            if value is None:
                self._short += 1
                continue
            self._tracker.add(float(getattr(message, "timestamp", 0.0)), value)

    def close(self) -> None:
        if self._source is not None:
            self._source.close()


class _Locks:
    """The update locks an open gate holds until the cutover is over."""

    def __init__(self, locks: UpdateLocks) -> None:
        self._locks = locks

    def release(self) -> None:
        self._locks.release()


def _describe(vehicle: VehicleSpec) -> str:
    src = vehicle.source
    if src.bus is not None:
        return f"bus {src.bus.get('interface')} {src.bus.get('channel', '')}".strip()
    return f"follow {src.follow}" if src.follow is not None else f"log {src.log}"


@dataclass
class VehicleListener:
    """The ids an app puts on the bus (`health.can`), read from the same source as the
    gates: a recording's frames since the app started, then new ones as they come."""

    vehicle: VehicleSpec
    layout: Layout
    base_dir: Path
    monotonic: Callable[[], float] = time.monotonic

    def heard(self, ids: Sequence[int], *, since: float, within: float) -> set[int]:
        wanted, seen = set(ids), set[int]()
        deadline = self.monotonic() + within
        try:
            source = open_vehicle_source(self.vehicle, layout=self.layout, base_dir=self.base_dir,
                                         ids=list(wanted))
        except VehicleSourceError:
            return seen  # nothing can be heard: the check fails, naming the ids
        try:
            backlog = source.backlog(max(0.0, time.time() - since) + within)
            for message in itertools.chain(backlog, source.frames(deadline)):
                if message.timestamp >= since and message.arbitration_id in wanted:
                    seen.add(message.arbitration_id)
                    if seen == wanted:
                        break
        finally:
            source.close()
        return seen


def open_vehicle_source(vehicle: VehicleSpec, *, layout: Layout, base_dir: Path,
                        ids: Sequence[int] = ()) -> FrameSource:
    """The frames `vehicle.source` names, paths taken under --root (relative ones from the
    desired state's folder). On a bus, only `ids` are asked for (python-can's `can_filters`,
    in the kernel for socketcan): a RAV4 bus carries thousands of frames a second, and
    lpam reads it beside the experiment."""
    from reconciler.adapters.can.sources import open_source

    def path(text: str) -> Path:
        return layout.under(text) if text.startswith("/") else base_dir / text

    src = vehicle.source
    if src.bus is not None:
        config: dict[str, object] = dict(src.bus)
        if ids and "can_filters" not in config:
            config["can_filters"] = [{"can_id": i, "can_mask": 0x1FFFFFFF if i > 0x7FF
                                      else 0x7FF, "extended": i > 0x7FF} for i in ids]
        return open_source(bus=config)
    if src.follow is not None:
        return open_source(follow=path(src.follow))
    assert src.log is not None
    return open_source(log=path(src.log))
