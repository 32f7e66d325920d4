"""The span of a data file (adapters/spans.py): the recordings the car's apps write, in the
formats they write them (libpanda's CSVs, candump's log, rosbag v2), whole, torn by a
writer mid-line or a power cut, huge, or not recordings at all; and whether a file is
finished, against a real process holding it open.

The files are generated here: the real drive (../shared/data) is read only by
tests/integration/test_spans_real.py.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from datetime import datetime, timezone
from pathlib import Path

import pytest

from reconciler.adapters import spans
from reconciler.adapters.can.csvlog import HEADER
from reconciler.adapters.spans import Span, finished, open_paths, span, vehicle_of

VIN = "JTMB6RFV5MD000123"
T0 = 1628870267.291576  # the real drive's first frame
GPS_HEADER = "Gpstime,Status,Long,Lat,Alt,HDOP,PDOP,VDOP,Systime"


def at(seconds: float) -> datetime:
    """`seconds` since the epoch as the reader gives it: UTC, to the microsecond."""
    whole = int(seconds)
    micro = round((seconds - whole) * 1_000_000)
    return datetime.fromtimestamp(whole, timezone.utc).replace(microsecond=micro)


def csv_rows(times: Sequence[float]) -> str:
    """libpanda's rows (Can::writeCsvToFile): time, bus, id in decimal, hex data, length."""
    return "".join(f"{t:.6f},0,180,00000000600000{i % 256:02x},8\n" for i, t in enumerate(times))


def candump_lines(times: Sequence[float]) -> str:
    return "".join(f"({t:.6f}) can0 0B4#00000000600000{i % 256:02X}\n" for i, t in enumerate(times))


def pandacord_name(kind: str = "CAN") -> str:
    return f"2021-08-13-18-57-47_{VIN}_{kind}_Messages.csv"


def big_csv(path: Path, megabytes: int = 20) -> tuple[float, float]:
    """A libpanda CSV of about `megabytes` MB, written in blocks; its first and last times."""
    row_bytes = len(csv_rows([T0]))
    count = megabytes * 1_000_000 // row_bytes
    with path.open("w") as out:
        out.write(HEADER + "\n")
        for start in range(0, count, 50_000):
            out.write(csv_rows([T0 + i * 0.001 for i in range(start, min(count, start + 50_000))]))
    return T0, T0 + (count - 1) * 0.001


def touch(path: Path, seconds: float) -> None:
    """Set the file's times to `seconds`, to the microsecond (a float would miss it)."""
    ns = round(seconds * 1_000_000) * 1000
    os.utime(path, ns=(ns, ns))


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The byte counts of every pread the reader makes (it reads with pread only)."""
    sizes: list[int] = []
    real = os.pread

    def pread(fd: int, length: int, offset: int) -> bytes:
        data = real(fd, length, offset)
        sizes.append(len(data))
        return data

    monkeypatch.setattr(os, "pread", pread)
    return sizes


# --- libpanda's CSV -----------------------------------------------------------------------

def test_a_libpanda_csv_spans_its_first_and_last_rows_and_names_its_car(tmp_path: Path) -> None:
    path = tmp_path / pandacord_name()
    path.write_text(HEADER + "\n" + csv_rows([T0, T0 + 0.5, T0 + 61.25]))
    assert span(path) == Span(at(T0), at(T0 + 61.25), "csv", VIN, rows=3)


def test_a_20_mb_csv_is_read_at_its_ends_only(tmp_path: Path, reads: list[int]) -> None:
    path = tmp_path / "2021-08-13-18-57-47-CAN.csv"
    first, last = big_csv(path)
    assert path.stat().st_size > 19_000_000
    began = time.perf_counter()
    found = span(path)
    elapsed = time.perf_counter() - began
    assert found == Span(at(first), at(last), "csv", None, rows=None)
    assert sum(reads) <= 128 * 1024, reads  # 64 KiB from each end, of 20 MB
    assert elapsed < 0.5


def test_a_torn_last_row_is_skipped_even_when_its_time_is_whole(tmp_path: Path) -> None:
    """libpanda writes through a stdio buffer: the file ends wherever a flush cut it. The
    torn row's Time field may be complete and later than every whole row: still skipped."""
    for size in ("small", "large"):
        path = tmp_path / f"{size}.csv"
        if size == "large":
            _, last = big_csv(path, megabytes=2)
        else:
            last = T0 + 2
            path.write_text(HEADER + "\n" + csv_rows([T0, T0 + 1, last]))
        with path.open("a") as out:
            out.write(f"{last + 500:.6f},0,18")
        assert span(path).last == at(last), size
        assert span(path).first == at(T0), size


def test_a_power_cut_tail_of_nuls_is_not_a_row(tmp_path: Path) -> None:
    path = tmp_path / "cut.csv"
    path.write_bytes((HEADER + "\n" + csv_rows([T0, T0 + 3])).encode() + b"\0" * 8192)
    assert span(path) == Span(at(T0), at(T0 + 3), "csv", None, rows=2)


def test_the_gps_csv_is_timed_by_its_system_clock_column(tmp_path: Path) -> None:
    """libpanda's GPS file has no `Time` column: `Systime` is the clock the CAN file uses
    (Gpstime is the receiver's, converted in local time); rows end in CRLF."""
    rows = [f"{t - 3600:.6f},A,-86.7,36.1,180.0,0.90,1.50,1.20,{t:.6f}\r\n"
            for t in (T0, T0 + 1, T0 + 2)]
    path = tmp_path / pandacord_name("GPS")
    path.write_bytes((GPS_HEADER + "\r\n" + "".join(rows)).encode())
    assert span(path) == Span(at(T0), at(T0 + 2), "csv", VIN, rows=3)


def test_the_time_column_is_found_wherever_it_stands_quoted_or_not(tmp_path: Path) -> None:
    path = tmp_path / "other.csv"
    path.write_text('"Bus","Time",Note\n0,"1628870267.5",a\n1,1628870300.25,b\n')
    assert span(path) == Span(at(1628870267.5), at(1628870300.25), "csv", None, rows=2)


@pytest.mark.parametrize("text", [
    HEADER + "\n",                                    # header only: no rows yet
    HEADER + "\n1628870267.2915",                     # one torn row
    "Bus,Note\n0,1628870267.5\n",                     # no Time column
    "Time,Bus\n12.5,0\n13.0,0\n",                     # relative times: not dates
    "Time,Bus\nnan,0\ninf,0\n",
    "Time,Bus\n1628870267.5e99,0\n",
    "hello\nworld\n",
    "",
])
def test_a_csv_that_does_not_say_when_falls_back_to_file_times(
    tmp_path: Path, text: str
) -> None:
    path = tmp_path / "x.csv"
    path.write_text(text)
    touch(path, T0)
    assert span(path) == Span(None, at(T0), "file-times", None)


def test_binary_garbage_falls_back_to_file_times(tmp_path: Path) -> None:
    path = tmp_path / "noise.bin"
    path.write_bytes(os.urandom(300_000) + b"\n\xff\xfe,Time\n")
    touch(path, T0 + 9)
    assert span(path) == Span(None, at(T0 + 9), "file-times", None)


# --- candump -------------------------------------------------------------------------------

def test_a_candump_log_spans_its_first_and_last_lines(tmp_path: Path) -> None:
    path = tmp_path / "candump-2021-08-13_185747.log"
    path.write_text(candump_lines([T0, T0 + 0.016, T0 + 780.8]))
    assert span(path) == Span(at(T0), at(T0 + 780.8), "candump", None, rows=3)


def test_a_long_candump_log_is_read_at_its_ends_and_its_torn_line_skipped(
    tmp_path: Path, reads: list[int]
) -> None:
    path = tmp_path / "long.log"
    times = [T0 + i * 0.01 for i in range(200_000)]
    path.write_text(candump_lines(times) + f"({times[-1] + 9:.6f}) can0 0B4#0000")
    found = span(path)
    assert found == Span(at(times[0]), at(times[-1]), "candump", None, rows=None)
    assert sum(reads) <= 128 * 1024


# --- rosbag v2 -----------------------------------------------------------------------------

def _field(name: str, value: bytes) -> bytes:
    text = name.encode() + b"=" + value
    return struct.pack("<I", len(text)) + text


def _record(fields: dict[str, bytes], data: bytes) -> bytes:
    header = b"".join(_field(name, value) for name, value in fields.items())
    return struct.pack("<I", len(header)) + header + struct.pack("<I", len(data)) + data


def _time(seconds: float) -> bytes:
    micro = round(seconds * 1_000_000)  # to the microsecond, as the readers compare
    return struct.pack("<II", micro // 1_000_000, micro % 1_000_000 * 1000)


def write_bag(path: Path, chunks: Sequence[Sequence[float]], *, indexed: bool = True) -> None:
    """A rosbag v2 file as `rosbag record` leaves it (wiki.ros.org/Bags/Format/2.0): the
    version line, a bag header record padded to 4 KiB, uncompressed chunks of messages on
    one connection each followed by its index data, then the index: the connection record
    and one chunk info record a chunk. Unindexed: as a bag being written (index_pos 0)."""
    conn = struct.pack("<I", 0)
    connection = _record({"op": b"\x07", "conn": conn, "topic": b"/vel"},
                         b"".join([_field("topic", b"/vel"), _field("type", b"std_msgs/Float32"),
                                   _field("md5sum", b"73fcbf46b49191e672908e50842a83d4"),
                                   _field("message_definition", b"float32 data\n")]))
    body, infos = b"", []
    pos = len(b"#ROSBAG V2.0\n") + 4096
    for times in chunks:
        inner = connection + b"".join(
            _record({"op": b"\x02", "conn": conn, "time": _time(t)}, struct.pack("<f", 1.0))
            for t in times)
        chunk = _record({"op": b"\x05", "compression": b"none",
                         "size": struct.pack("<I", len(inner))}, inner)
        index = _record({"op": b"\x04", "ver": struct.pack("<I", 1), "conn": conn,
                         "count": struct.pack("<I", len(times))},
                        b"".join(_time(t) + struct.pack("<I", 0) for t in times))
        infos.append(_record({"op": b"\x06", "ver": struct.pack("<I", 1),
                              "chunk_pos": struct.pack("<Q", pos),
                              "start_time": _time(min(times)), "end_time": _time(max(times)),
                              "count": struct.pack("<I", 1)},
                             struct.pack("<II", 0, len(times))))
        body += chunk + index
        pos += len(chunk) + len(index)
    header = b"".join([_field("op", b"\x03"),
                       _field("index_pos", struct.pack("<Q", pos if indexed else 0)),
                       _field("conn_count", struct.pack("<I", 1)),
                       _field("chunk_count", struct.pack("<I", len(chunks) if indexed else 0))])
    padding = b" " * (4096 - 8 - len(header))
    bag_header = struct.pack("<I", len(header)) + header + struct.pack("<I", len(padding)) + padding
    index_section = connection + b"".join(infos) if indexed else b""
    path.write_bytes(b"#ROSBAG V2.0\n" + bag_header + body + index_section)


def test_a_bag_spans_its_chunks_by_their_index(tmp_path: Path, reads: list[int]) -> None:
    """Chunk times need not be in order: the span is the earliest start to the latest end."""
    path = tmp_path / f"circles_{VIN}_2021-08-13-18-57-47.bag"
    chunks = [[T0 + i * 0.1 for i in range(5_000)], [T0 - 2, T0 + 900.5], [T0 + 600, T0 + 601]]
    write_bag(path, chunks)
    assert span(path) == Span(at(T0 - 2), at(T0 + 900.5), "rosbag", VIN, rows=5_004)
    assert path.stat().st_size > 100_000
    assert sum(reads) < 64 * 1024 + 1024  # the head, then the index: not the messages


def test_a_bag_still_being_written_falls_back_to_file_times(tmp_path: Path) -> None:
    path = tmp_path / "live.bag.active"
    write_bag(path, [[T0, T0 + 1]], indexed=False)
    touch(path, T0 + 5)
    assert span(path) == Span(None, at(T0 + 5), "file-times", None)


@pytest.mark.parametrize("damage", ["cut index", "cut header", "sim time", "wrong op"])
def test_a_damaged_or_undated_bag_falls_back_to_file_times(tmp_path: Path, damage: str) -> None:
    path = tmp_path / "x.bag"
    write_bag(path, [[12.0, 13.0]] if damage == "sim time" else [[T0, T0 + 1], [T0 + 2]])
    data = path.read_bytes()
    if damage == "cut index":
        data = data[:-7]
    elif damage == "cut header":
        data = data[:40]
    elif damage == "wrong op":
        data = data.replace(b"op=\x03", b"op=\x09", 1)
    path.write_bytes(data)
    touch(path, T0)
    assert span(path) == Span(None, at(T0), "file-times", None)


# --- what is not a regular file ------------------------------------------------------------

def _within(seconds: float, path: Path) -> Span:
    """span(path), failing rather than hanging when it does not return in time."""
    result: list[Span] = []
    worker = threading.Thread(target=lambda: result.append(span(path)), daemon=True)
    worker.start()
    worker.join(seconds)
    assert result, f"span({path}) did not return within {seconds} s"
    return result[0]


def test_a_fifo_a_device_a_directory_and_a_missing_file_never_hang_nor_raise(
    tmp_path: Path
) -> None:
    fifo = tmp_path / "2021-08-13-18-57-47-CAN.csv"
    os.mkfifo(fifo)
    assert _within(5, fifo).source == "file-times"
    assert _within(5, Path("/dev/zero")).source == "file-times"
    assert _within(5, tmp_path).source == "file-times"
    assert span(tmp_path / "gone.csv") == Span(None, None, "file-times", None)


def test_a_data_file_reached_through_a_link_is_read(tmp_path: Path) -> None:
    data = tmp_path / "data.log"
    data.write_text(candump_lines([T0, T0 + 1]))
    link = tmp_path / f"{VIN}.log"
    link.symlink_to(data)
    assert span(link) == Span(at(T0), at(T0 + 1), "candump", VIN, rows=2)


# --- the vehicle ---------------------------------------------------------------------------

@pytest.mark.parametrize(("name", "vin"), [
    (pandacord_name(), VIN),
    (f"2021-08-13-18-57-47{VIN}_CAN_Messages.csv", VIN),   # pandarecord.sh's FILENAME_PRE
    ("2021-08-13-18-57-47-CAN.csv", None),                 # pandazone: no VIN
    ("16288702672915760_can.log", None),                   # a number, not a car
    ("JTMB6RFV5MD00012O.bag", None),                       # O is no VIN letter
    (f"X{VIN}.bag", None),                                 # 18 characters
])
def test_the_vehicle_is_the_vin_in_the_name(name: str, vin: str | None) -> None:
    assert vehicle_of(name) == vin


# --- finished ------------------------------------------------------------------------------

@pytest.fixture
def holder(tmp_path: Path) -> Iterator[tuple[Path, subprocess.Popen[str]]]:
    """A real process that holds a data file open for writing until its stdin closes."""
    path = tmp_path / "held.csv"
    path.write_text(HEADER + "\n")
    child = subprocess.Popen(
        [sys.executable, "-c",
         "import sys; f = open(sys.argv[1], 'a'); print('open', flush=True); sys.stdin.read()",
         str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None and child.stdout.readline() == "open\n"
    yield path, child
    if child.poll() is None:
        child.kill()
        child.wait()


def test_a_file_a_process_holds_open_is_not_finished_until_it_exits(
    holder: tuple[Path, subprocess.Popen[str]]
) -> None:
    path, child = holder
    later = path.stat().st_mtime + 3600
    assert not finished(path, now=later)
    assert os.path.realpath(path) in open_paths()
    assert child.stdin is not None
    child.stdin.close()
    child.wait(timeout=10)
    assert finished(path, now=later)


def test_the_file_libpanda_is_recording_is_not_finished(tmp_path: Path) -> None:
    old, current = tmp_path / "a-CAN.csv", tmp_path / "b-CAN.csv"
    for path in (old, current):
        path.write_text(HEADER + "\n")
    link = tmp_path / "currentCan.csv"
    link.symlink_to(current)
    later = current.stat().st_mtime + 3600
    assert not finished(current, now=later, current_link=link, held=())
    assert finished(old, now=later, current_link=link, held=())
    link.unlink()  # libpanda removes the link, then makes it anew: for a moment, none
    assert finished(current, now=later, current_link=link, held=())


def test_a_file_written_within_the_quiet_time_is_not_finished(tmp_path: Path) -> None:
    path = tmp_path / "x.log"
    path.write_text("")
    touch(path, T0)
    assert not finished(path, now=T0 + 59, held=())
    assert not finished(path, now=T0 - 100, held=())  # written "in the future": wait
    assert finished(path, now=T0 + 61, held=())
    assert finished(path, now=T0 + 11, quiet_seconds=10, held=())
    assert not finished(tmp_path / "gone", now=T0 + 61, held=())


def test_the_scan_of_proc_passes_over_what_it_cannot_read(tmp_path: Path) -> None:
    """A process that ends mid-scan leaves a pid without fd/, or fd entries that are no
    longer links; neither stops the scan from finding a writer further on."""
    data = tmp_path / "data.csv"
    data.write_text("")
    touch(data, T0)
    proc = tmp_path / "proc"
    (proc / "12").mkdir(parents=True)                  # gone: no fd/
    (proc / "13").mkdir()
    (proc / "13" / "fd").write_text("")                # not a directory
    (proc / "14" / "fd").mkdir(parents=True)
    (proc / "14" / "fd" / "3").write_text("")          # not a link
    (proc / "self").mkdir()                            # not a pid
    (proc / "15" / "fd").mkdir(parents=True)
    (proc / "15" / "fd" / "4").symlink_to(data)
    assert not finished(data, now=T0 + 3600, proc=proc)
    (proc / "15" / "fd" / "4").unlink()
    assert finished(data, now=T0 + 3600, proc=proc)
    assert open_paths(tmp_path / "no-proc") == frozenset()


def test_limits_are_what_the_docstring_promises() -> None:
    assert spans.HEAD_BYTES == spans.TAIL_BYTES == 64 * 1024
