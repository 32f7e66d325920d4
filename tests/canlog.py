"""The drive for the CAN tests, and writers that make recordings of it as the car does.

`drive()` is the RAV4 drive that tests/drive.py generates from a speed profile: there in
every clone. `recorded_drive()` is a real 13-minute drive of a RAV4 Hybrid, read where
`../shared/data/` lies beside the checkout, for the checks that the generated drive makes
the same decisions as a real one; without it those tests are skipped, saying why (its
repository states no licence, so no copy of it is kept here). `write_csv` and
`write_candump` put frames into the two text formats lpam follows; `CsvWriter` and
`CandumpWriter` append them in a background thread at the drive's pace, so a test can
follow a file that grows as libpanda's or `candump -l`'s does — optionally in blocks that
split lines anywhere, as libpanda's stdio buffer does. Writers stop when their `with`
block ends, waiting a fraction of a second at most.
"""

from __future__ import annotations

import functools
import gzip
import re
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import TracebackType
from typing import TextIO

import can
import pytest

from reconciler.adapters.can.csvlog import HEADER
from tests.drive import SPEED_ID as SPEED_ID
from tests.drive import candump_line as candump_line
from tests.drive import frames as generated_frames

RECORDED = "rav4-hybrid-2021-08-13.candump.log"
TICK = 0.1


def drive() -> list[can.Message]:
    """The generated drive's ~62,000 frames (tests/drive.py), made once a process."""
    return list(generated_frames())


def recorded_path() -> Path:
    """Where the real recording lies when it is there: `../shared/data/` from the checkout."""
    return Path(__file__).resolve().parent.parent.parent / "shared" / "data" / RECORDED


def recorded_drive() -> list[can.Message]:
    """The real drive's 56,323 frames, read once a process; skips the test, saying why,
    where it is absent."""
    return list(_load(_recorded_or_skip()))


def recorded_text() -> str:
    """The real drive as candump text (for tests that read its lines themselves)."""
    with _text(_recorded_or_skip()) as text:
        return text.read()


def _recorded_or_skip() -> Path:
    path = recorded_path()
    if not path.is_file():
        pytest.skip(f"the recorded RAV4 drive is not at {path} (../shared/data beside the "
                    "checkout): this check against the real recording is skipped; the "
                    "generated drive of tests/drive.py stands in for it everywhere else")
    return path


def read_log(path: Path) -> list[can.Message]:
    """A candump log's frames, gzip-compressed or not."""
    return list(_load(path))


@functools.cache
def _load(path: Path) -> tuple[can.Message, ...]:
    with _text(path) as text:
        return tuple(can.CanutilsLogReader(text))


def _text(path: Path) -> TextIO:
    """The log as text, gzip-compressed or not."""
    return gzip.open(path, "rt") if path.suffix == ".gz" else path.open()


def speed_kmh(msg: can.Message) -> float | None:
    """The speed in a SPEED (0xB4) frame: bytes 5-6 big-endian, 0.01 km/h."""
    if msg.arbitration_id != SPEED_ID or len(msg.data) < 7:
        return None
    return int.from_bytes(msg.data[5:7], "big") * 0.01


def between(frames: Sequence[can.Message], start: float, end: float) -> list[can.Message]:
    """The frames from `start` to `end` seconds into `frames` (the drive's first frame: 0)."""
    first = frames[0].timestamp
    return [m for m in frames if start <= m.timestamp - first < end]


def shifted(msg: can.Message, shift: float) -> can.Message:
    """`msg` stamped `shift` seconds later, to the microsecond, as the text formats keep it."""
    return can.Message(
        timestamp=float(f"{msg.timestamp + shift:.6f}"), arbitration_id=msg.arbitration_id,
        is_extended_id=msg.is_extended_id, channel=msg.channel, dlc=msg.dlc,
        data=msg.data, is_fd=msg.is_fd)


def bus_number(channel: object) -> int:
    """candump's `can0` is libpanda's bus 0."""
    if isinstance(channel, int):
        return channel
    match = re.search(r"(\d+)$", str(channel or ""))
    return int(match.group(1)) if match else 0


def csv_row(msg: can.Message, shift: float = 0.0) -> str:
    """A libpanda CSV row (as `Can::writeCsvToFile` prints it), with its newline."""
    stamp = f"{msg.timestamp + shift:.6f}"
    return (f"{stamp},{bus_number(msg.channel)},{msg.arbitration_id},"
            f"{bytes(msg.data).hex()},{len(msg.data)}\n")


def write_csv(path: Path, frames: Sequence[can.Message], *, shift: float = 0.0,
              header: bool = True) -> None:
    """A libpanda CSV of `frames`, stamped `shift` seconds later than recorded."""
    text = (HEADER + "\n" if header else "") + "".join(csv_row(m, shift) for m in frames)
    path.write_text(text)


def write_candump(path: Path, frames: Sequence[can.Message], *, shift: float = 0.0) -> None:
    path.write_text("".join(candump_line(m, shift) for m in frames))


class ProgressiveWriter:
    """Appends `frames` to `path` in a thread, each when its time has come: the recording's
    pace times `speed`, starting at once. Each frame is stamped `shift` seconds later than
    recorded (None: so that the first is stamped now, as a live recording would). With
    `block`, text is written and flushed `block` bytes at a time, cutting lines anywhere."""

    def __init__(self, path: Path, frames: Sequence[can.Message], *,
                 line: Callable[[can.Message, float], str], shift: float | None = None,
                 speed: float = 1.0, block: int | None = None) -> None:
        self.path = path
        self.frames = list(frames)
        self.line = line
        if shift is None:
            shift = time.time() - self.frames[0].timestamp if self.frames else 0.0
        self.shift = shift
        self.speed = speed
        self.block = block
        self.written = 0  # frames whose whole line is in the file
        self.done = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> ProgressiveWriter:
        self._thread.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)

    def _run(self) -> None:
        if not self.frames:
            self.done.set()
            return
        began, first = time.monotonic(), self.frames[0].timestamp
        pending = ""
        with self.path.open("a") as out:
            for msg in self.frames:
                due = began + (msg.timestamp - first) / self.speed
                while (left := due - time.monotonic()) > 0:
                    if self._stop.wait(min(left, TICK)):
                        return
                if self._stop.is_set():
                    return
                pending += self.line(msg, self.shift)
                size = len(pending) if self.block is None else \
                    len(pending) - len(pending) % self.block
                out.write(pending[:size])
                out.flush()
                self.written += pending[:size].count("\n")
                pending = pending[size:]
            out.write(pending)
            self.written += pending.count("\n")
        self.done.set()


class CsvWriter(ProgressiveWriter):
    """libpanda writing its CSV during a drive."""

    def __init__(self, path: Path, frames: Sequence[can.Message], *,
                 shift: float | None = None, speed: float = 1.0,
                 block: int | None = None) -> None:
        super().__init__(path, frames, line=csv_row, shift=shift, speed=speed, block=block)


class CandumpWriter(ProgressiveWriter):
    """`candump -l` writing its log during a drive."""

    def __init__(self, path: Path, frames: Sequence[can.Message], *,
                 shift: float | None = None, speed: float = 1.0,
                 block: int | None = None) -> None:
        super().__init__(path, frames, line=candump_line, shift=shift, speed=speed,
                         block=block)
