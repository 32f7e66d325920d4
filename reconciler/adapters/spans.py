"""The time span of a data file an app wrote, read from the file's own timestamps.

Place in the flow: provenance (issue 33) names, for each data file on the car, the app
generations that ran while it was written. That needs the file's first and last moments,
and whether the file is finished (a file still being written has no last moment yet). This
module only reads; it never writes, and never raises on a bad file: a recording cut by the
ignition ends in anything (a torn line, a block of NULs after a power cut), so content it
cannot read gives the file's own times instead, and says so (`source="file-times"`).

Formats read, each from its head and its tail only (a drive's CSV grows to GBs; a Pi must
pay the same for it as for a small one: at most HEAD_BYTES + TAIL_BYTES of a text file):

- libpanda's CSV (`Can::saveToCsvFile`, pandazone): a header line
  `Time,Bus,MessageID,Message,MessageLength`, rows `1628870267.291576,0,180,…,8` where Time
  is gettimeofday() at reception. Its GPS file has no `Time` column but
  `Gpstime,…,Systime`: Systime is the same system clock (Gpstime is the receiver's,
  converted with mktime in local time, so it is not used). Other columns are tolerated.
- candump's log (`candump -l`): `(1615712345.123456) can0 123#DEADBEEF`.
- rosbag v2 (`#ROSBAG V2.0`): the bag header record gives index_pos; the chunk info
  records after it hold each chunk's start and end time, so only the index is read. A
  bag still being written (index_pos 0) has no index yet: file times.

A text file's last moment is its last COMPLETE line: the writer's stdio buffer leaves the
last line half written. Times before 2000 or after 2100 are not wall-clock dates (relative
times, a simulated clock) and are not taken as such.

The vehicle is the VIN in the file's name: pandacord named its files
`2021-08-13-18-57-47_<VIN>_CAN_Messages.csv` (an older script glued the VIN to the date
without the `_`); pandazone's `2021-08-13-18-57-47-CAN.csv` carries none (the VIN is in
/etc/libpanda.d/vin), and then `vehicle` is None.
"""

from __future__ import annotations

import os
import re
import struct
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from decimal import Decimal
from pathlib import Path
from typing import Literal

from reconciler.base.reading import KIB, MIB, open_regular

HEAD_BYTES = 64 * KIB       # read from a text file's start: its header and first rows
TAIL_BYTES = 64 * KIB       # read back from its end for the last complete row
INDEX_LIMIT = 16 * MIB      # a bag's index (~100 bytes a 768 KiB chunk): 16 MiB is ~100 GB
EARLIEST = 946684800        # 2000-01-01: before it a "time" is relative, not a date
LATEST = 4102444800         # 2100-01-01
_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)
_BAG_MAGIC = b"#ROSBAG V2.0\n"
_OP_BAG_HEADER, _OP_CHUNK_INFO = 0x03, 0x06
_CANDUMP = re.compile(rb"\((\d+\.\d+)\)\s+\S+\s+\S+")
_TIME_COLUMNS = ("time", "systime")  # in order of preference, compared without case
_VIN = re.compile(r"[A-HJ-NPR-Z0-9]{17}")
_RUN = re.compile(r"[A-Z0-9]+")
_STAMP_PREFIX = re.compile(r"^\d{4}-\d{2}-\d{2}-\d{2}-\d{2}-\d{2}")

Source = Literal["csv", "candump", "rosbag", "file-times"]


@dataclass(frozen=True)
class Span:
    """When a file's content begins and ends, and what says so.

    `first`/`last` are UTC-aware; None where not known (file times know no beginning).
    `rows` is given only where it costs nothing more (a small text file read whole, a bag's
    index), never by reading a large file through."""

    first: datetime | None
    last: datetime | None
    source: Source
    vehicle: str | None
    rows: int | None = None


class _Unreadable(ValueError):
    """Content that is not what its first bytes promised: the caller falls back."""


def span(path: Path) -> Span:
    """The span of `path`, from its content where it is a format this module reads, else
    from its modification time. Never raises: a missing or unreadable file has no times."""
    vehicle = vehicle_of(path.name)
    fd = open_regular(path)  # non-blocking, regular files only: never a FIFO's hang
    if fd is None:
        return _file_times(path, vehicle, None)
    try:
        found = _from_content(fd, vehicle)
        return found if found is not None else _file_times(path, vehicle, fd)
    except (OSError, ValueError, ArithmeticError, struct.error, LookupError):
        return _file_times(path, vehicle, fd)
    finally:
        os.close(fd)


def _from_content(fd: int, vehicle: str | None) -> Span | None:
    size = os.fstat(fd).st_size
    head = os.pread(fd, min(HEAD_BYTES, size), 0)
    if head.startswith(_BAG_MAGIC):
        return _rosbag(fd, head, size, vehicle)
    tail = head if size <= HEAD_BYTES else os.pread(fd, TAIL_BYTES, size - TAIL_BYTES)
    whole = size <= HEAD_BYTES
    lines = list(_complete_lines(head, from_start=True))
    if not lines:
        return None
    if _CANDUMP.match(lines[0]):
        return _text_span(lines, tail, whole, _candump_time, "candump", vehicle)
    column = _time_column(lines[0])
    if column is None:
        return None
    return _text_span(lines[1:], tail, whole, lambda line: _csv_time(line, column), "csv",
                      vehicle)


def _file_times(path: Path, vehicle: str | None, fd: int | None) -> Span:
    """The fallback: the content does not say, so the last write is the last moment known
    and the beginning is unknown (creation time is not kept by every file system)."""
    try:
        mtime = os.fstat(fd).st_mtime_ns if fd is not None else os.stat(path).st_mtime_ns
    except OSError:
        return Span(None, None, "file-times", vehicle)
    return Span(None, _from_ns(mtime), "file-times", vehicle)


def _complete_lines(data: bytes, *, from_start: bool) -> Iterator[bytes]:
    """The whole lines of `data`, without line ends: the piece after the last newline is a
    torn line (or a power cut's NULs) and is left out; so is the piece before the first
    newline unless `data` starts the file."""
    end = data.rfind(b"\n")
    if end < 0:
        return
    begin = 0 if from_start else data.find(b"\n") + 1
    if begin > end:
        return
    for line in data[begin:end].split(b"\n"):
        yield line.rstrip(b"\r")


def _text_span(rows: list[bytes], tail: bytes, whole: bool,
               stamp: Callable[[bytes], datetime | None], source: Source,
               vehicle: str | None) -> Span | None:
    """First = the first row that has a time; last = the last complete row that has one,
    from the tail. A torn or garbled row is skipped, never taken as an end."""
    first = next((t for t in map(stamp, rows) if t is not None), None)
    tail_rows = list(_complete_lines(tail, from_start=whole))
    last = next((t for t in map(stamp, reversed(tail_rows)) if t is not None), None)
    if first is None or last is None:
        return None
    counted = sum(1 for row in rows if stamp(row) is not None) if whole else None
    return Span(first, last, source, vehicle, counted)


def _time_column(header: bytes) -> int | None:
    """The index of the column whose name is `Time` (else `Systime`), quotes and a UTF-8
    byte order mark tolerated; None when the first line is no such header."""
    try:
        text = header.decode("utf-8").lstrip("\ufeff")
    except UnicodeDecodeError:
        return None
    names = [name.strip().strip('"').strip().lower() for name in text.split(",")]
    for wanted in _TIME_COLUMNS:
        if wanted in names:
            return names.index(wanted)
    return None


def _csv_time(row: bytes, column: int) -> datetime | None:
    fields = row.split(b",")
    return _seconds(fields[column].strip().strip(b'"')) if len(fields) > column else None


def _candump_time(line: bytes) -> datetime | None:
    match = _CANDUMP.match(line)
    return _seconds(match.group(1)) if match else None


def _seconds(text: bytes) -> datetime | None:
    """`1628870267.291576` as a UTC datetime, to the microsecond: parsed as a decimal, as a
    float would round the sixteenth digit. None for anything else or for a non-date."""
    if not text or len(text) > 40 or not text.replace(b".", b"", 1).isdigit():
        return None
    value = Decimal(text.decode("ascii"))
    if not EARLIEST <= value < LATEST:
        return None
    whole = int(value)
    return _EPOCH + timedelta(seconds=whole, microseconds=int((value - whole) * 1_000_000))


def _from_ns(ns: int) -> datetime:
    return _EPOCH + timedelta(microseconds=ns // 1000)



def _rosbag(fd: int, head: bytes, size: int, vehicle: str | None) -> Span | None:
    """A bag's span from its index: the chunk info records after index_pos hold each
    chunk's start and end time and its message counts, so the GBs of messages before them
    are never read. None (file times) for a bag with no index yet, or an absurd one."""
    fields, _padding, header_end = _record(head, len(_BAG_MAGIC))
    if fields.get("op") != bytes([_OP_BAG_HEADER]):
        raise _Unreadable("the first record is not a bag header")
    (index_pos,) = struct.unpack("<Q", fields["index_pos"])
    (chunk_count,) = struct.unpack("<I", fields["chunk_count"])
    if index_pos == 0 or not header_end <= index_pos < size or size - index_pos > INDEX_LIMIT:
        return None  # still being written (rosbag writes the index on close), or damaged
    index = os.pread(fd, size - index_pos, index_pos)
    starts: list[datetime | None] = []
    ends: list[datetime | None] = []
    rows = at = 0
    while at < len(index):
        fields, data, at = _record(index, at)
        if fields.get("op") != bytes([_OP_CHUNK_INFO]):
            continue  # the connection records that precede the chunk infos
        starts.append(_bag_time(fields["start_time"]))
        ends.append(_bag_time(fields["end_time"]))
        (connections,) = struct.unpack("<I", fields["count"])
        rows += sum(count for _conn, count in struct.iter_unpack("<II", data[:8 * connections]))
    if len(starts) != chunk_count or not starts:
        return None
    known_starts = [t for t in starts if t is not None]
    known_ends = [t for t in ends if t is not None]
    if not known_starts or not known_ends:
        return None  # a simulated clock: no dates
    return Span(min(known_starts), max(known_ends), "rosbag", vehicle, rows)


def _record(buf: bytes, at: int) -> tuple[dict[str, bytes], bytes, int]:
    """The record at `at`: `<header_len><header><data_len><data>`, lengths little-endian
    uint32; the header a sequence of `<field_len>name=value`. Returns its fields, its data
    and where the next record starts; a record cut short is _Unreadable."""
    (header_len,) = struct.unpack_from("<I", buf, at)
    header = buf[at + 4:at + 4 + header_len]
    at += 4 + header_len
    (data_len,) = struct.unpack_from("<I", buf, at)
    data = buf[at + 4:at + 4 + data_len]
    if len(header) != header_len or len(data) != data_len:
        raise _Unreadable("a record is cut short")
    fields: dict[str, bytes] = {}
    pos = 0
    while pos < len(header):
        (field_len,) = struct.unpack_from("<I", header, pos)
        field = header[pos + 4:pos + 4 + field_len]
        name, equals, value = field.partition(b"=")
        if len(field) != field_len or not equals:
            raise _Unreadable("a header field is cut short")
        fields[name.decode("ascii")] = value
        pos += 4 + field_len
    return fields, data, at + 4 + data_len


def _bag_time(value: bytes) -> datetime | None:
    """A ros::Time: seconds and nanoseconds, little-endian uint32 each."""
    sec, nsec = struct.unpack("<II", value)
    if not EARLIEST <= sec < LATEST or nsec >= 1_000_000_000:
        return None
    return _EPOCH + timedelta(seconds=sec, microseconds=nsec // 1000)


def vehicle_of(name: str) -> str | None:
    """The VIN in a file's name: a run of 17 of the letters and digits a VIN may hold (no
    I, O, Q), with both letters and digits (a 17-digit number is a timestamp, not a car).
    pandacord's date prefix is dropped first, as one of its scripts glued the VIN to it."""
    rest = _STAMP_PREFIX.sub("", name, count=1)
    for match in _RUN.finditer(rest):
        run = match.group()
        if (len(run) == 17 and _VIN.fullmatch(run) and any(c.isdigit() for c in run)
                and any(c.isalpha() for c in run)):
            return run
    return None


def finished(path: Path, *, now: float, quiet_seconds: float = 60.0,
             current_link: Path | None = None, proc: Path = Path("/proc"),
             held: Collection[str] | None = None) -> bool:
    """Whether `path` is done being written, so its span is final. Not while libpanda's
    `current_link` (/etc/libpanda.d/currentCan.csv) points at it, nor while it was written
    within `quiet_seconds` of `now` (a writer between two buffer flushes holds no lock),
    nor while any process has it open. A file that cannot be seen is not finished.

    `held` is `open_paths(proc)` taken once by a caller that asks about many files: the
    scan of /proc costs a few ms a time on a Pi."""
    try:
        info = os.stat(path)
    except OSError:
        return False
    if current_link is not None and _same_file(current_link, info):
        return False
    if now - info.st_mtime < quiet_seconds:
        return False  # in the future too: a clock set back cannot tell, so wait
    open_now = held if held is not None else open_paths(proc)
    return os.path.realpath(path) not in open_now


def _same_file(link: Path, info: os.stat_result) -> bool:
    try:
        target = os.stat(link)  # libpanda removes, then relinks: for a moment, no link
    except OSError:
        return False
    return (target.st_dev, target.st_ino) == (info.st_dev, info.st_ino)


def open_paths(proc: Path = Path("/proc")) -> frozenset[str]:
    """Every path some process holds open: the targets of /proc/<pid>/fd/*. A process that
    ends meanwhile, or whose descriptors this user may not read, is passed over (so, not
    run as root, other users' writers are not seen: lpam runs as root on the car)."""
    found: set[str] = set()
    try:
        pids = [entry.path for entry in os.scandir(proc) if entry.name.isdigit()]
    except OSError:
        return frozenset()
    for pid in pids:
        fds = os.path.join(pid, "fd")
        try:
            names = os.listdir(fds)
        except OSError:
            continue
        for name in names:
            try:
                found.add(os.readlink(os.path.join(fds, name)))
            except OSError:
                continue
    return frozenset(found)
