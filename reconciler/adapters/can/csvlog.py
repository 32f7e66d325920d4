"""The car's recordings as text: libpanda's CSV and candump's log, read from their end and
followed as they grow.

On the car the recording app (libpanda) writes every frame the panda receives to a CSV
file and points `/etc/libpanda.d/currentCan.csv` at it; a new recording re-points the link
(remove, then symlink: for a moment there is no link at all). An update gate reads the
speed from there, not from the panda, because the panda's USB belongs to the one app that
owns the vehicle. This module owns that format (libpanda `Can::writeCsvToFile`):

    Time,Bus,MessageID,Message,MessageLength
    1628880000.123456,0,180,0000000000001a2b,8

time is gettimeofday() at reception (seconds.microseconds), bus the panda's bus number
(0x80 or 0x40 or-ed in for frames it returned or rejected), the arbitration id in decimal,
the data as hex, two digits a byte, up to 64 bytes (CAN FD), and its length in bytes.

`parse_row` and `parse_candump` (one line of `candump -l`) are pure and never raise: a
recording cut by the ignition ends in anything. `Follower` is the I/O, the same for both
formats. libpanda writes through stdio buffers, so the last line is often half written: only
complete lines reach a parser. A recording grows to hundreds of MB in a drive, so the
backlog is read back from the end in growing chunks, never from the start.
"""

from __future__ import annotations

import io
import os
import re
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import can

HEADER = "Time,Bus,MessageID,Message,MessageLength"
POLL_SECONDS = 0.15         # between two looks at a file that did not grow
FIRST_CHUNK = 64 * 1024     # read back from the end for a backlog, doubled until it is enough
BACKLOG_LIMIT = 64 << 20    # never read more than this for one backlog (a Pi has little RAM)
READ_LIMIT = 1 << 20        # new data taken in one read; a longer "line" is garbage
_ROW = re.compile(r"(\d+(?:\.\d+)?),(\d+),(\d+),((?:[0-9a-fA-F]{2})*),(\d+)")
_MAX_ID = 0x1FFFFFFF

Ident = tuple[int, int]  # (st_dev, st_ino): which file a name leads to


def parse_row(line: str) -> can.Message | None:
    """The frame of one libpanda CSV row; None for the header, a blank or malformed row."""
    match = _ROW.fullmatch(line.rstrip("\r\n"))
    if match is None:
        return None
    stamp, bus, ident, data, length = match.groups()
    payload = bytes.fromhex(data)
    arbitration_id = int(ident)
    if int(length) != len(payload) or arbitration_id > _MAX_ID:
        return None
    return can.Message(
        timestamp=float(stamp), arbitration_id=arbitration_id,
        is_extended_id=arbitration_id > 0x7FF, channel=int(bus), dlc=len(payload),
        data=payload, is_fd=len(payload) > 8)


def parse_candump(line: str) -> can.Message | None:
    """The frame of one `candump -l` line, read by python-can's own reader (it has no
    parser for a single line, so the line is handed to it as a whole file)."""
    if not line.strip():
        return None
    try:
        return next(iter(can.CanutilsLogReader(io.StringIO(line))), None)
    except Exception:  # whatever a garbled line makes python-can's reader trip on
        return None


def _csv_filler(line: str) -> bool:
    text = line.strip()
    return not text or text == HEADER


def _blank(line: str) -> bool:
    return not line.strip()


@dataclass(frozen=True)
class LineFormat:
    """How to read one line of a text recording. `filler` lines (blank, a header) are not
    frames and not faults either: they are not counted as skipped."""

    name: str
    parse: Callable[[str], can.Message | None]
    filler: Callable[[str], bool]


LIBPANDA = LineFormat("libpanda CSV", parse_row, _csv_filler)
CANDUMP = LineFormat("candump log", parse_candump, _blank)


class Follower:
    """One text recording of frames, read back from its end, then followed as it grows.

    `path` may be a symlink that the writer re-points or a file that is replaced: when the
    name leads to another file, the rest of the old one is read and the new one is followed
    from its start. While the name leads nowhere, or the file cannot be read, there is
    silence; a caller sees no frames, which a gate reads as "no signal".
    """

    def __init__(self, path: Path, fmt: LineFormat, *, poll: float = POLL_SECONDS) -> None:
        self.path = path
        self.format = fmt
        self.poll = poll
        self.skipped = 0
        self._file: BinaryIO | None = open(path, "rb")  # noqa: SIM115  (held until close)
        self._ident = _ident_of(self._file)
        self.current = Path(os.path.realpath(path))
        self._pos: int | None = None  # the end of the complete lines handed out so far

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def backlog(self, seconds: float) -> list[can.Message]:
        """The frames within `seconds` of the newest complete line, oldest first; `frames`
        continues right after them."""
        if self._file is None:
            return []
        try:
            end = self._complete_end(self._file)
            entries = self._tail(self._file, end, seconds)
        except OSError:
            return []
        self._pos = end
        stamps = [msg.timestamp for msg, _ in entries if msg is not None]
        if not stamps:
            self.skipped += sum(bad for _, bad in entries)
            return []
        cutoff = max(stamps) - seconds
        first = 0  # the window starts after the last frame older than it
        for index, (msg, _) in enumerate(entries):
            if msg is not None and msg.timestamp < cutoff:
                first = index + 1
        window = entries[first:]
        self.skipped += sum(bad for _, bad in window)
        return [msg for msg, _ in window if msg is not None and msg.timestamp >= cutoff]

    def frames(self, deadline: float) -> Iterator[can.Message]:
        """New frames as their lines are completed, until time.monotonic() >= deadline."""
        if self._pos is None and self._file is not None:
            try:
                self._pos = self._complete_end(self._file)
            except OSError:
                self._lose()
        while time.monotonic() < deadline:
            lines = self._read_new()
            if lines:
                if (yield from self._emit(lines, deadline)):
                    return
                continue
            successor = self._successor()
            if successor is not None:
                # what the writer added to the old file before it moved on comes first
                if (yield from self._emit(self._read_new(), deadline)):
                    successor.close()
                    return
                self._switch(successor)
                continue
            time.sleep(max(0.0, min(self.poll, deadline - time.monotonic())))

    def _emit(self, lines: list[bytes], deadline: float) -> Generator[can.Message, None, bool]:
        """Yield the frames of `lines`, moving the position line by line; True when the
        deadline ended it (the next call resumes at the first line not handed out)."""
        for raw in lines:
            if time.monotonic() >= deadline:
                return True
            assert self._pos is not None
            self._pos += len(raw) + 1
            msg, bad = self._decode(raw)
            self.skipped += bad
            if msg is not None:
                yield msg
        return False

    def _decode(self, raw: bytes) -> tuple[can.Message | None, bool]:
        line = raw.decode("utf-8", errors="replace")
        if self.format.filler(line):
            return None, False
        msg = self.format.parse(line)
        return msg, msg is None

    def _read_new(self) -> list[bytes]:
        """The complete lines written after the position (without their newlines)."""
        if self._file is None or self._pos is None:
            return []
        try:
            self._file.seek(self._pos)
            data = self._file.read(READ_LIMIT)
        except OSError:
            self._lose()
            return []
        end = data.rfind(b"\n")
        if end < 0:
            if len(data) >= READ_LIMIT:  # no frame is this long: step over the garbage
                self._pos += len(data)
                self.skipped += 1
            return []
        return data[:end].split(b"\n")

    def _successor(self) -> BinaryIO | None:
        """The file the name leads to now, opened, when it is not the one being read."""
        try:
            named = os.stat(self.path)
        except OSError:
            return None  # libpanda removes the link before it makes the new one
        if (named.st_dev, named.st_ino) == self._ident and self._file is not None:
            if self._pos is not None and named.st_size < self._pos:
                self._pos = 0  # truncated and written again from the start
            return None
        try:
            return open(self.path, "rb")
        except OSError:
            return None

    def _switch(self, successor: BinaryIO) -> None:
        ident = _ident_of(successor)
        if ident != self._ident:
            self._pos = 0  # a new recording: all of it is new
        elif self._pos is None:
            try:
                self._pos = self._complete_end(successor)
            except OSError:
                self._pos = 0
        self.close()
        self._file, self._ident = successor, ident
        self.current = Path(os.path.realpath(self.path))

    def _lose(self) -> None:
        """The open file failed: read nothing more from it; a later look at the name may
        find it (or a successor) again."""
        self.close()

    def _tail(
        self, file: BinaryIO, end: int, seconds: float
    ) -> list[tuple[can.Message | None, bool]]:
        """Decoded lines of the shortest tail of [0, end) that holds a frame older than
        `seconds` before its newest one (or of all of it)."""
        chunk = FIRST_CHUNK
        while True:
            start = max(0, end - chunk)
            file.seek(start)
            lines = file.read(end - start).split(b"\n")[:-1]
            if start > 0:
                lines = lines[1:]  # the chunk may begin inside a line
            entries = [self._decode(raw) for raw in lines]
            stamps = [msg.timestamp for msg, _ in entries if msg is not None]
            covered = bool(stamps) and stamps[0] < max(stamps) - seconds
            if covered or start == 0 or chunk >= BACKLOG_LIMIT:
                return entries
            chunk *= 2

    @staticmethod
    def _complete_end(file: BinaryIO) -> int:
        """The end of the last complete line; a half-written one waits for its newline."""
        size = os.fstat(file.fileno()).st_size
        pos = size
        while pos > 0 and size - pos < READ_LIMIT:
            step = min(4096, pos)
            file.seek(pos - step)
            at = file.read(step).rfind(b"\n")
            if at >= 0:
                return pos - step + at + 1
            pos -= step
        return 0 if pos == 0 else size


def _ident_of(file: BinaryIO) -> Ident:
    info = os.fstat(file.fileno())
    return info.st_dev, info.st_ino
