"""One contract for every frame source a gate reads the vehicle from, each fed the same
stretch of the generated drive (tests/drive.py; the car at about 57.7 km/h, 330 s into it):

- bus: python-can's socketcand client against `tests.socketcand` replaying it live;
- follow: a libpanda CSV behind a `currentCan.csv` symlink, written as the drive goes on;
- log: a `candump -l` log, written as the drive goes on.

What a gate relies on is written once for all three: `backlog` is exactly the last seconds
recorded before the source was opened (none for a bus), oldest first; `frames` hands over
what arrives next with no gap and no repeat and stops at its deadline, asleep while nothing
comes; a source that goes away ends in silence, never in an exception; every fault opening
one is a `VehicleSourceError` of one line that says what to do. What only files have — a
half-written line, malformed rows, a re-pointed link, a replaced file, a recording of
hundreds of MB — is checked for both file sources.

Every server and writer is stopped and every source closed at teardown; files live in the
test's tmp_path; the only sockets are on 127.0.0.1. Windows are a second or so.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import pytest

from reconciler.adapters.can.csvlog import HEADER
from reconciler.adapters.can.sources import FrameSource, open_source
from reconciler.base.errors import VehicleSourceError
from schemas.vehicle import BUS_INTERFACES
from tests.canlog import (
    CandumpWriter,
    CsvWriter,
    ProgressiveWriter,
    between,
    candump_line,
    csv_row,
    drive,
    shifted,
    speed_kmh,
    write_candump,
    write_csv,
)
from tests.gitserver import closed_port
from tests.hostile_servers import HostileServer
from tests.socketcand import SocketcandServer

KINDS = ["bus", "follow", "log"]
FILES = ["follow", "log"]
OFFSET = 330.0   # seconds into the drive: moving at about 57.7 km/h
HISTORY = 4.0    # seconds recorded before a file source is opened
LATE = 0.35      # how long after its deadline `frames` may still be running

Key = tuple[int, bytes]


def key(msg: can.Message) -> Key:
    return msg.arbitration_id, bytes(msg.data)


def keys(frames: list[can.Message]) -> list[Key]:
    return [key(m) for m in frames]


def window(frames: list[can.Message], seconds: float) -> list[can.Message]:
    if not frames:
        return []
    newest = max(m.timestamp for m in frames)
    return [m for m in frames if m.timestamp >= newest - seconds]


def run_of(got: list[can.Message], expected: list[can.Message]) -> int | None:
    """Where `got` sits in `expected` as one unbroken run (None: it is not one)."""
    want, have = keys(expected), keys(got)
    for start in range(len(want) - len(have) + 1):
        if want[start:start + len(have)] == have:
            return start
    return None


def collect(source: FrameSource, seconds: float) -> tuple[list[can.Message], float]:
    """All `frames` yields in `seconds`, and how late after its deadline it returned."""
    deadline = time.monotonic() + seconds
    got = list(source.frames(deadline))
    return got, time.monotonic() - deadline


@dataclass
class Feed:
    """A source under test and what it must see. `history` was recorded before it was
    opened (as stamped in the file; none for a bus); `live` arrives once `start()` is
    called (for a bus: is arriving already, stamped when sent)."""

    kind: str
    source: FrameSource
    history: list[can.Message]
    live: list[can.Message]
    path: Path | None = None           # the file written (a symlink's target)
    start: Callable[[], None] = lambda: None
    stop: Callable[[], None] = lambda: None    # the source's far end goes away
    line: Callable[[can.Message, float], str] = csv_row
    shift: float = 0.0
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def files(self) -> bool:
        return self.kind != "bus"


@pytest.fixture
def feed(tmp_path: Path) -> Iterator[Callable[..., Feed]]:
    """`feed(kind, *, speed=1.0, block=None, silent=False)`: a source fed from the drive."""
    with contextlib.ExitStack() as stack:

        def make(kind: str, *, speed: float = 1.0, block: int | None = None,
                 silent: bool = False) -> Feed:
            frames = drive()
            live = between(frames, OFFSET, OFFSET + 30)
            if kind == "bus":
                server = stack.enter_context(SocketcandServer(
                    frames, offset=1e6 if silent else OFFSET, speed=speed))
                source = open_source(bus=server.config())
                stack.callback(source.close)
                return Feed(kind, source, [], live, stop=server.stop,
                            extras={"server": server})
            shift = time.time() - live[0].timestamp  # the live part begins now
            history = [shifted(m, shift) for m in between(frames, OFFSET - HISTORY, OFFSET)]
            writer: ProgressiveWriter
            if kind == "follow":
                path = tmp_path / "2021-08-13-18-57-47.csv"
                write_csv(path, history)
                link = tmp_path / "currentCan.csv"
                link.symlink_to(path)
                writer = CsvWriter(path, live, shift=shift, speed=speed, block=block)
                source = open_source(follow=link)
                line = csv_row
            else:
                path = tmp_path / "drive.log"
                write_candump(path, history)
                writer = CandumpWriter(path, live, shift=shift, speed=speed, block=block)
                source = open_source(log=path)
                line = candump_line
            stack.callback(source.close)
            stack.callback(writer.stop)

            def start() -> None:
                writer.__enter__()

            return Feed(kind, source, history, [shifted(m, shift) for m in live], path=path,
                        start=start, stop=writer.stop, line=line, shift=shift,
                        extras={"writer": writer})

        yield make


# --- backlog -------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", KINDS)
def test_backlog_is_the_last_seconds_recorded_oldest_first(
        feed: Callable[..., Feed], kind: str) -> None:
    f = feed(kind)
    edge = f.history[-40].timestamp if f.files else 0.0  # a frame right at the window's start
    newest = f.history[-1].timestamp if f.files else 0.0
    for seconds in (0.5, 2.0, newest - edge, 100.0):
        got = f.source.backlog(seconds)
        expected = window(f.history, seconds)
        assert keys(got) == keys(expected), seconds
        assert [m.timestamp for m in got] == [m.timestamp for m in expected]
        assert all(a.timestamp <= b.timestamp for a, b in zip(got, got[1:]))
    if f.files:
        assert 0.5 * 60 < len(f.source.backlog(1.0)) < 1.5 * 100  # 80 frames a second
    assert f.source.skipped == 0


@pytest.mark.parametrize("kind", FILES)
def test_backlog_reads_only_the_end_of_a_long_recording(
        feed: Callable[..., Feed], kind: str) -> None:
    """A drive's CSV reaches hundreds of MB: the backlog must not read it from the start.
    The recording here is 64 MB of junk followed by the drive's last seconds; the bytes
    this process reads (/proc/self/io) tell how much of it was touched."""
    io_stats = Path("/proc/self/io")
    if not io_stats.exists():
        pytest.skip("no /proc/self/io to count the bytes read")
    f = feed(kind)
    assert f.path is not None
    tail = f.path.read_bytes()
    with f.path.open("r+b") as out:
        out.truncate(0)
        out.write(tail[:40] + b"\n")  # a first line, then a 64 MB hole of NUL bytes
        out.seek(64 << 20)
        out.write(b"\n" + tail)

    def read_so_far() -> int:
        return int(io_stats.read_text().split("rchar:")[1].split()[0])

    before = read_so_far()
    got = f.source.backlog(2.0)
    f.start()
    later, _ = collect(f.source, 0.3)
    assert read_so_far() - before < 2 << 20
    assert keys(got) == keys(window(f.history, 2.0))
    assert keys(later) == keys(f.live[:len(later)]) and later


# --- frames --------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", KINDS)
def test_frames_go_on_from_the_backlog_with_no_gap_or_repeat_and_stop_at_the_deadline(
        feed: Callable[..., Feed], kind: str) -> None:
    f = feed(kind)
    back = f.source.backlog(1.0)
    f.start()
    first, late_first = collect(f.source, 0.8)
    second, late_second = collect(f.source, 0.5)
    assert 0 <= late_first < LATE and 0 <= late_second < LATE
    assert len(first) > 25 and len(second) > 15  # 80 frames a second
    if f.files:  # the file holds everything: backlog + frames is the drive, in order
        got = back + first + second
        expected = window(f.history, 1.0) + f.live[:len(first) + len(second)]
        assert keys(got) == keys(expected)
        assert [m.timestamp for m in got] == pytest.approx([m.timestamp for m in expected])
    else:  # a bus has no history and what went by before connecting is gone
        assert back == []
        assert run_of(first + second, f.live) is not None
        assert all(abs(m.timestamp - time.time()) < 5 for m in first)  # stamped when sent
    speeds = [s for m in first + second if (s := speed_kmh(m)) is not None]
    assert speeds and all(50 < s < 60 for s in speeds)


@pytest.mark.parametrize("kind", KINDS)
def test_silence_lasts_until_the_deadline_asleep(feed: Callable[..., Feed], kind: str) -> None:
    """Nothing arrives: `frames` yields nothing, returns at its deadline, and spends its
    time asleep (lpam runs beside the experiment on a Pi)."""
    f = feed(kind, silent=True)
    cpu = time.thread_time()
    got, late = collect(f.source, 0.6)
    assert got == []
    assert 0 <= late < LATE
    assert time.thread_time() - cpu < 0.06


@pytest.mark.parametrize("kind", KINDS)
def test_a_source_that_goes_away_ends_in_silence_not_an_exception(
        feed: Callable[..., Feed], kind: str) -> None:
    """The server hangs up, or the recording is deleted: the stream goes quiet (the gate
    reads it as "no signal"), without raising and without spinning."""
    f = feed(kind)
    f.source.backlog(1.0)
    f.start()
    before, _ = collect(f.source, 0.3)
    assert before
    f.stop()
    if f.files:
        assert f.path is not None
        f.path.unlink()
        if kind == "follow":
            (f.path.parent / "currentCan.csv").unlink()
    collect(f.source, 0.2)  # what was on its way when the source went
    cpu = time.thread_time()
    after, late = collect(f.source, 0.5)
    assert after == []
    assert 0 <= late < LATE
    assert time.thread_time() - cpu < 0.1


def test_a_garbled_socketcand_frame_ends_the_bus_stream_quietly(
        feed: Callable[..., Feed]) -> None:
    """python-can's socketcand client keeps failing on a frame it cannot parse (it stays
    in its buffer): the source goes silent rather than raise."""
    f = feed("bus")
    assert collect(f.source, 0.3)[0]
    f.extras["server"].inject("< frame XYZ 1.0 00 >")  # in the source's socket on return
    got, late = collect(f.source, 0.5)
    assert 0 <= late < LATE
    again, _ = collect(f.source, 0.3)
    assert again == []
    assert len(got) < 10


# --- what only files have ------------------------------------------------------------------

@pytest.mark.parametrize("kind", FILES)
def test_a_half_written_line_waits_for_its_newline(feed: Callable[..., Feed], kind: str) -> None:
    f = feed(kind)
    assert f.path is not None
    f.source.backlog(1.0)
    text = f.line(f.live[0], 0.0)
    with f.path.open("a") as out:
        out.write(text[: len(text) // 2])
    assert collect(f.source, 0.4)[0] == []
    with f.path.open("a") as out:
        out.write(text[len(text) // 2:])
    got, _ = collect(f.source, 0.4)
    assert keys(got) == [key(f.live[0])]
    assert got[0].timestamp == pytest.approx(f.live[0].timestamp)
    assert f.source.skipped == 0


@pytest.mark.parametrize("kind", FILES)
def test_lines_cut_anywhere_by_the_writers_buffer_arrive_whole(
        feed: Callable[..., Feed], kind: str) -> None:
    """libpanda writes through stdio: the file grows in blocks that end mid-line."""
    f = feed(kind, speed=3.0, block=37)
    f.source.backlog(0.5)
    f.start()
    got, _ = collect(f.source, 1.2)
    assert len(got) > 100
    assert keys(got) == keys(f.live[:len(got)])
    assert f.source.skipped == 0


BAD_ROWS = {
    "follow": ["1628870600.5,0,180,zz11,2", "1628870600.5,0,180,0011,3", "1628870600.5,0,180",
               "1628870600.5,0,180,0011,2,9", "\x00\x00\x00 garbage", "1628870600.5,0,180,001,1",
               "nan,0,180,00,1"],
    "log": ["(1628870600.5) can0 0B4#ZZ", "(x) can0 0B4#00", "can0 0B4#00",
            "\x00\x00\x00 garbage", "(1628870600.5) can0 0B4"],
}
FILLER = {"follow": ["", HEADER], "log": [""]}  # not frames, and not faults either


@pytest.mark.parametrize("kind", FILES)
def test_malformed_rows_are_skipped_and_counted(feed: Callable[..., Feed], kind: str) -> None:
    f = feed(kind)
    assert f.path is not None
    bad, filler = BAD_ROWS[kind], FILLER[kind]
    good = f.live[:6]
    with f.path.open("a") as out:  # recorded before the backlog is taken
        for index, msg in enumerate(good[:3]):
            out.write(f"{bad[index]}\n{f.line(msg, 0.0)}")
        out.write("".join(f"{line}\n" for line in [*filler, *bad[3:]]))
    back = f.source.backlog(0.5)
    assert keys(back) == keys(window(f.history + good[:3], 0.5))
    assert f.source.skipped == len(bad)
    arriving = [*filler, f.line(good[3], 0.0), bad[0], f.line(good[4], 0.0), *bad[1:],
                f.line(good[5], 0.0)]
    with f.path.open("a") as out:  # and arriving while frames are read
        out.write("".join(line if line.endswith("\n") else f"{line}\n" for line in arriving))
    got, _ = collect(f.source, 0.4)
    assert keys(got) == keys(good[3:])
    assert f.source.skipped == 2 * len(bad)


@pytest.mark.parametrize("kind", FILES)
def test_a_replaced_file_is_read_from_its_start(feed: Callable[..., Feed], kind: str) -> None:
    """A new recording in place of the old one (another inode under the same name)."""
    f = feed(kind)
    assert f.path is not None
    f.source.backlog(1.0)
    assert collect(f.source, 0.2)[0] == []
    newer = f.live[100:130]
    fresh = f.path.with_name("fresh.tmp")
    if kind == "follow":
        write_csv(fresh, newer)
    else:
        write_candump(fresh, newer)
    os.replace(fresh, f.path)
    got, _ = collect(f.source, 0.5)
    assert keys(got) == keys(newer)


def test_a_repointed_link_is_followed_to_the_new_recording(feed: Callable[..., Feed]) -> None:
    """libpanda starts a new recording: a new CSV, and `currentCan.csv` removed and made
    again pointing at it. What the old file got last is read first, then the new file
    from its first row; the description names the new target."""
    f = feed("follow")
    assert f.path is not None
    link = f.path.parent / "currentCan.csv"
    f.source.backlog(1.0)
    assert "2021-08-13-18-57-47.csv" in f.source.description
    last_of_old, first_of_new = f.live[:5], f.live[5:]
    with f.path.open("a") as out:
        out.write("".join(csv_row(m) for m in last_of_old))
    newer = f.path.with_name("2021-08-13-19-10-00.csv")
    newer.write_text(HEADER + "\n")
    link.unlink()
    link.symlink_to(newer)
    with CsvWriter(newer, first_of_new, shift=0.0, speed=2.0):
        got, _ = collect(f.source, 0.8)
    assert len(got) > 40
    assert keys(got) == keys(f.live[:len(got)])
    assert f.source.description == f"follow {link} → {newer}"
    assert f.source.skipped == 0


# --- errors --------------------------------------------------------------------------------

def _cases(tmp: Path, hostile_port: int, server: SocketcandServer, closed: int
           ) -> dict[str, tuple[dict[str, Any], list[str], str]]:
    """name -> (open_source arguments, words the message must hold, words of the hint);
    `closed`: a port that refuses connections."""
    (tmp / "folder").mkdir()
    (tmp / "dangling.csv").symlink_to(tmp / "gone.csv")
    (tmp / "notes.txt").write_text("hello\n")
    (tmp / "broken.blf").write_bytes(b"this is no BLF file" * 10)
    wrong_channel = {**server.config(), "channel": "can7"}
    return {
        "follow-missing": ({"follow": tmp / "nope.csv"}, ["no such file", "nope.csv"],
                           "recording app"),
        "follow-dangling": ({"follow": tmp / "dangling.csv"}, ["no such file", "points to",
                                                                "gone.csv"], "vehicle.source"),
        "follow-folder": ({"follow": tmp / "folder"}, ["is a directory"], "currentCan.csv"),
        "log-missing": ({"log": tmp / "drive.log"}, ["no such file", "drive.log"],
                        "recording app"),
        "log-folder": ({"log": tmp / "folder"}, ["is a directory"], "file"),
        "log-unknown-format": ({"log": tmp / "notes.txt"}, ["reads no .txt files"], ".blf"),
        "log-broken": ({"log": tmp / "broken.blf"}, ["cannot read it", "broken.blf"],
                       "complete log"),
        "bus-unknown-interface": ({"bus": {"interface": "nope", "channel": "can0"}},
                                  ["no interface 'nope'"], "socketcand"),
        "bus-no-interface": ({"bus": {"channel": "can0"}}, ["names no interface"], "virtual"),
        "bus-socketcand-no-host": ({"bus": {"interface": "socketcand", "channel": "can0"}},
                                   ["needs a host"], "port"),
        "bus-nothing-listening": ({"bus": {"interface": "socketcand", "host": "127.0.0.1",
                                           "port": closed, "channel": "can0"}},
                                  ["cannot connect", "refused"], "socketcand running"),
        "bus-silent-server": ({"bus": {"interface": "socketcand", "host": "127.0.0.1",
                                       "port": hostile_port, "channel": "can0"},
                               "timeout": 1.0}, ["no answer within 1 s"], "vehicle.source.bus"),
        "bus-wrong-channel": ({"bus": wrong_channel}, ["cannot open the bus", "error"],
                              "vehicle.source.bus"),
        "none": ({}, ["exactly one", "none"], "follow:"),
        "two": ({"follow": tmp / "a.csv", "log": tmp / "b.log"}, ["follow and log"], "follow:"),
    }


def test_every_fault_opening_a_source_is_one_line_that_says_what_to_do(tmp_path: Path) -> None:
    with HostileServer() as hostile, SocketcandServer(drive()[:10]) as server, \
            closed_port() as closed:
        cases = _cases(tmp_path, hostile.port, server, closed)
        for name, (arguments, words, hint) in cases.items():
            began = time.monotonic()
            with pytest.raises(VehicleSourceError) as caught:
                open_source(**arguments)
            error = caught.value
            assert time.monotonic() - began < 2.0, name
            assert all(word in error.message for word in words), (name, error.message)
            assert error.hint is not None and hint in error.hint, (name, error.hint)
            assert "\n" not in error.message and "Traceback" not in error.render(), name
            assert error.__cause__ is None, name  # python-can's exception is not carried


def test_a_bus_source_names_where_it_listens(feed: Callable[..., Feed]) -> None:
    f = feed("bus")
    port = f.extras["server"].port
    assert f.source.description == f"socketcand can0 at 127.0.0.1:{port}"
    assert f.source.skipped == 0


def test_a_desired_state_may_name_every_interface_python_can_ships() -> None:
    """schemas/ imports no CAN library, so schemas/vehicle.py writes out the names a
    desired state's `bus: {interface: …}` may use; they must be the ones this python-can
    ships (its BACKENDS less any a plugin adds from outside can.interfaces)."""
    shipped = {name for name, (module, _) in can.interfaces.BACKENDS.items()
               if module.startswith("can.interfaces.")}
    assert tuple(sorted(shipped)) == BUS_INTERFACES
