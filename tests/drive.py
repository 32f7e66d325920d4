"""A RAV4 drive made up for the tests: a `candump -l` log generated from a speed profile
shaped like a real drive, so that the update gates are tested wherever the repository is
cloned, with nothing in it that someone else recorded.

The gates decide from one signal, the speed, and from how long it has been at zero; what
they must get right is the shape of a drive: a car that stands, drives, stops briefly at a
junction, stops at a light, and parks. `PROFILE` is that shape (seconds into the drive,
km/h), joined by straight lines — constant acceleration, about 1 m/s², as a car pulls away
and brakes:

      0 - 121    standing, as a car does before it leaves
    121 - 143    out of the parking space at walking pace, then a short stop (143-147 s)
    147 - 265    up to about 57.7 km/h and on at that speed
    265 - 281    braking for a light; stands from 280.75 to 299 s (18 s: not parked)
    299 - 481    on at 57.7, then traffic: slower, faster, a turn
    481 - 642    town, 5-29 km/h
    642 - 669    into a car park: a stop (651-654 s), reversing into the space
    669 - 780    parked

The speed frame is the RAV4's own: message 0xB4 (SPEED) of opendbc's `_toyota_2017.dbc`,
`SPEED : 47|16@0+ (0.01,0)` km/h — bytes 5-6 big-endian — with byte 4 a wheel-encoder
count and byte 7 Toyota's checksum, four times a second at phase 0.02 s; so the first
standing sample of a stop comes 0.02 s after the stop above (280.77 s, 668.77 s). While the
car moves, its speed wobbles by a few hundredths, as a cruising car's does; standing, it is
exactly 0. Seven other ids share the bus, so that every reader must filter by id: 0xAA
(WHEEL_SPEEDS, four 16-bit wheel speeds offset by 67.67 km/h, so never zero even when the
car stands) and six whose payload is a rolling counter and a checksum, 2 to 8 bytes long.
Every id repeats at its own period; each frame is late by up to 1.5 ms, as bus arbitration
makes it. That is about 80 frames a second, the density of the RAV4 recording the tests were
first written against (a panda's log, not the full bus's thousands a second), so the tests
that replay the drive in real time cost what they did.

Everything is deterministic: the wobble and the lateness come from `random.Random` with
fixed seeds (Python keeps `random()` the same across versions for an integer seed), and
timestamps are rounded to the microsecond that candump writes. Write the log with
`python -m tests.drive OUT.log` (`OUT.log.gz`: gzip-compressed).
"""

from __future__ import annotations

import argparse
import bisect
import functools
import gzip
import math
import random
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import can

START = 1_717_236_000.0  # the drive's first instant, epoch seconds (arbitrary, fixed)
DURATION = 780.0
SEED = 18
JITTER = 0.0015  # seconds a frame may be late after its period
SPEED_ID = 0x0B4
WHEEL_SPEEDS_ID = 0x0AA
SPEED_PERIOD = 0.25
SPEED_PHASE = 0.02
CRUISE = 57.7
STANDING_BELOW = 5.0  # km/h under which the speed does not wobble

PROFILE: tuple[tuple[float, float], ...] = (
    (0.0, 0.0), (121.0, 0.0),                   # standing
    (127.0, 6.0), (141.0, 6.0), (143.25, 0.0),  # out of the parking space; a short stop
    (147.25, 0.0), (163.0, 40.0), (175.0, CRUISE), (265.0, CRUISE),
    (280.75, 0.0), (299.0, 0.0),                # braking for a light; standing at it
    (312.0, CRUISE), (346.0, CRUISE), (356.0, 28.0), (362.0, 28.0), (384.0, 58.0),
    (400.0, 58.0), (410.0, 24.0), (428.0, 56.0), (438.0, 54.0), (446.0, 48.0),
    (456.0, 54.0), (466.0, 46.0), (481.0, 5.0),  # traffic, then a turn
    (500.0, 28.0), (508.0, 14.0), (520.0, 25.0), (526.0, 15.0), (546.0, 22.0),
    (564.0, 9.0), (573.0, 29.0), (590.0, 5.0), (600.0, 11.0), (612.0, 7.0),
    (628.0, 5.0),                                # town
    (642.0, 3.0), (650.0, 3.0), (651.25, 0.0), (654.0, 0.0),  # a car park: stop, reverse
    (655.0, 3.0), (667.75, 3.0), (668.75, 0.0),  # into the space
    (DURATION, 0.0),                             # parked
)


@dataclass(frozen=True)
class Frame:
    """One id on the bus: every `period` seconds from `phase`, `length` bytes."""

    ident: int
    length: int
    period: float
    phase: float


FRAMES = (
    Frame(0x025, 8, 0.05, 0.000),
    Frame(WHEEL_SPEEDS_ID, 8, 0.10, 0.004),
    Frame(SPEED_ID, 8, SPEED_PERIOD, SPEED_PHASE),
    Frame(0x1D2, 8, 0.20, 0.013),
    Frame(0x224, 7, 0.10, 0.031),
    Frame(0x260, 5, 0.05, 0.022),
    Frame(0x2C1, 6, 0.10, 0.047),
    Frame(0x3BC, 2, 1.00, 0.509),
)

_TIMES = [t for t, _ in PROFILE]


def profile_speed(t: float) -> float:
    """The profile's speed at `t` seconds into the drive (km/h, before the wobble)."""
    if t <= 0.0 or t >= DURATION:
        return 0.0
    right = bisect.bisect_right(_TIMES, t)
    (t0, v0), (t1, v1) = PROFILE[right - 1], PROFILE[right]
    return v0 + (v1 - v0) * (t - t0) / (t1 - t0)


def checksum(ident: int, data: bytes) -> int:
    """Toyota's checksum, the last byte of its frames: the id's bytes, the length and every
    other byte, summed, modulo 256 (opendbc's `toyota_checksum`)."""
    return ((ident >> 8) + (ident & 0xFF) + len(data) + sum(data[:-1])) & 0xFF


def speed_data(kmh: float, encoder: int) -> bytes:
    """A SPEED frame: bytes 5-6 the speed in 0.01 km/h, big-endian."""
    raw = round(kmh * 100)
    data = bytearray([0, 0, 0, 0, encoder & 0xFF, raw >> 8, raw & 0xFF, 0])
    data[7] = checksum(SPEED_ID, bytes(data))
    return bytes(data)


def wheel_speeds_data(kmh: float) -> bytes:
    """WHEEL_SPEEDS: four wheels, each 16 bits big-endian of (speed + 67.67) / 0.01."""
    raw = round((kmh + 67.67) * 100)
    return raw.to_bytes(2, "big") * 4


def counter_data(ident: int, length: int, count: int) -> bytes:
    """A frame that only counts: a rolling counter (at byte 5 where there is room, so that
    bytes 5-6 are never the SPEED of a frame read without its id) and the checksum."""
    data = bytearray(length)
    data[min(5, length - 2)] = count & 0xFF
    data[-1] = checksum(ident, bytes(data))
    return bytes(data)


@functools.cache
def speeds() -> tuple[tuple[float, float], ...]:
    """Every SPEED sample of the drive, (seconds into the drive, km/h), before the lateness
    of its frame: the profile plus the wobble of a moving car, rounded to 0.01 km/h."""
    rng = random.Random(SEED)
    found = []
    count = math.ceil((DURATION - SPEED_PHASE) / SPEED_PERIOD)
    for k in range(count):
        t = SPEED_PHASE + k * SPEED_PERIOD
        base = profile_speed(t)
        wobble = 0.12 * math.sin(2 * math.pi * t / 19) + rng.uniform(-0.05, 0.05)
        kmh = base + wobble if base >= STANDING_BELOW else base
        found.append((t, round(kmh, 2)))
    return tuple(found)


def _speed_then(t: float) -> float:
    """The last SPEED sample at or before `t` (what the car's other ECUs agree on)."""
    samples = speeds()
    index = max(0, math.floor((t - SPEED_PHASE) / SPEED_PERIOD))
    return samples[min(index, len(samples) - 1)][1]


@functools.cache
def frames() -> tuple[can.Message, ...]:
    """The whole drive, in time order, stamped from `START`."""
    stamped: list[tuple[float, int, bytes]] = []
    encoder, distance_m = 0, 0.0
    for spec in FRAMES:
        late = random.Random(SEED * 0x1000 + spec.ident)
        count = math.ceil((DURATION - spec.phase) / spec.period)
        for k in range(count):
            t = spec.phase + k * spec.period
            if spec.ident == SPEED_ID:
                kmh = speeds()[k][1]
                distance_m += kmh / 3.6 * SPEED_PERIOD
                encoder = int(distance_m * 4)  # a count every 25 cm, as wheels turn
                data = speed_data(kmh, encoder)
            elif spec.ident == WHEEL_SPEEDS_ID:
                data = wheel_speeds_data(_speed_then(t))
            else:
                data = counter_data(spec.ident, spec.length, k)
            stamp = round(START + t + late.uniform(0.0, JITTER), 6)
            stamped.append((stamp, spec.ident, data))
    stamped.sort()
    return tuple(
        can.Message(timestamp=stamp, arbitration_id=ident, is_extended_id=False,
                    channel="can0", dlc=len(data), data=data)
        for stamp, ident, data in stamped)


def candump_line(msg: can.Message, shift: float = 0.0) -> str:
    """A `candump -l` line, with its newline."""
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    channel = msg.channel if isinstance(msg.channel, str) else f"can{msg.channel or 0}"
    return f"({msg.timestamp + shift:.6f}) {channel} {ident}#{bytes(msg.data).hex().upper()}\n"


def write_log(path: Path, messages: Iterable[can.Message] | None = None) -> Path:
    """The drive (or `messages`) as a candump log at `path`, gzip-compressed when it ends
    in `.gz` (with no name or time in the gzip header, so that the bytes never change)."""
    text = "".join(candump_line(m) for m in (frames() if messages is None else messages))
    if path.suffix == ".gz":
        with path.open("wb") as raw, gzip.GzipFile(filename="", mode="wb", fileobj=raw,
                                                   mtime=0) as out:
            out.write(text.encode("ascii"))
    else:
        path.write_text(text)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.drive", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path, help="the log to write (.log, or .log.gz)")
    args = parser.parse_args(argv)
    write_log(args.out)
    print(f"{args.out}: {len(frames())} frames in {DURATION:g} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
