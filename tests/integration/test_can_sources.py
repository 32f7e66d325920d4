"""Frame sources against real parts in other processes: `tests.socketcand` run as its own
process and stopped by pid, an app that puts frames on the bus with python-can's own
socketcand client, logs written by python-can's writers, a recording the lpam user may not
read, and lpam's own process (what it imports, what it prints).

Speeds are decoded from the generated drive (tests/drive.py; SPEED 0xB4, bytes 5-6 times
0.01 km/h) only to show that what arrives is the car's traffic; the gate's decoding is
tested elsewhere.
"""

from __future__ import annotations

import os
import select
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from reconciler.adapters.can.csvlog import HEADER
from reconciler.adapters.can.sources import FrameSource, open_source
from tests.canlog import (
    CsvWriter,
    between,
    drive,
    shifted,
    speed_kmh,
    write_csv,
)
from tests.drive import write_log
from tests.socketcand import SocketcandServer

REPO = Path(__file__).resolve().parents[2]
PY = sys.executable


def key(msg: can.Message) -> tuple[int, bytes]:
    return msg.arbitration_id, bytes(msg.data)


def collect(source: FrameSource, seconds: float) -> list[can.Message]:
    return list(source.frames(time.monotonic() + seconds))


def run_python(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([PY, "-c", textwrap.dedent(code)], cwd=REPO, capture_output=True,
                          text=True, timeout=30, check=False)


@pytest.fixture
def socketcand_process(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], int]]:
    """`python -m tests.socketcand` replaying the drive, written as a gzip-compressed
    candump log, from 330 s (moving); its port."""
    path = write_log(tmp_path / "drive.log.gz")
    proc = subprocess.Popen(
        [PY, "-m", "tests.socketcand", str(path), "--offset", "330", "--port", "0"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 15)
        line = proc.stdout.readline() if ready else ""
        assert line.startswith("listening 127.0.0.1:"), line
        yield proc, int(line.rsplit(":", 1)[1])
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=5)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def test_a_socketcand_process_feeds_the_bus_source_until_it_is_stopped(
        socketcand_process: tuple[subprocess.Popen[str], int]) -> None:
    proc, port = socketcand_process
    source = open_source(bus={"interface": "socketcand", "host": "127.0.0.1", "port": port,
                              "channel": "can0"})
    try:
        got = collect(source, 1.0)
        assert len(got) > 40
        expected = [key(m) for m in between(drive(), 330, 360)]
        assert any(expected[i:i + len(got)] == [key(m) for m in got]
                   for i in range(len(expected)))
        speeds = [s for m in got if (s := speed_kmh(m)) is not None]
        assert speeds and all(50 < s < 60 for s in speeds)

        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=5) == 0
        cpu, began = time.thread_time(), time.monotonic()
        after = collect(source, 0.5)
        assert time.monotonic() - began < 0.8
        assert time.thread_time() - cpu < 0.1  # python-can alone would spin here
        # only frames already in flight when it stopped (how many depends on the machine's
        # load): a piece of the drive, then silence
        later = [key(m) for m in between(drive(), 330, 400)]
        assert any(later[i:i + len(after)] == [key(m) for m in after]
                   for i in range(len(later)))
        assert collect(source, 0.2) == []
    finally:
        source.close()


def test_frames_an_app_puts_on_the_bus_reach_the_source() -> None:
    """Another process — an app under test — sends with python-can's socketcand client
    (which writes data bytes unpadded: `a` for 0x0a); lpam's source hears it."""
    with SocketcandServer(drive(), offset=1e6) as server:  # a quiet bus
        source = open_source(bus=server.config())
        try:
            app = subprocess.Popen([PY, "-c", textwrap.dedent(f"""
                import can, time
                bus = can.Bus(interface="socketcand", host="127.0.0.1", port={server.port},
                              channel="can0")
                time.sleep(0.3)
                bus.send(can.Message(arbitration_id=0x7E0, is_extended_id=False,
                                     data=bytes([0x02, 0x0A, 0x00, 0xFF])))
                bus.send(can.Message(arbitration_id=0x18DAF110, is_extended_id=True,
                                     data=bytes([1, 2, 3])))
                time.sleep(0.3)
                bus.shutdown()
            """)], cwd=REPO)
            # what the source hears while the app runs (its start may take a while on a
            # busy machine), and what was still in flight when it ended
            got: list[can.Message] = []
            deadline = time.monotonic() + 30
            while app.poll() is None and time.monotonic() < deadline:
                got += collect(source, 0.2)
            got += collect(source, 0.5)
            assert app.wait(timeout=10) == 0
        finally:
            source.close()
    assert [(m.arbitration_id, bytes(m.data), m.is_extended_id) for m in got] == [
        (0x7E0, b"\x02\x0a\x00\xff", False), (0x18DAF110, b"\x01\x02\x03", True)]
    assert [key(m) for m in server.received] == [key(m) for m in got]


def test_the_speed_read_through_a_followed_recording_is_the_cars(tmp_path: Path) -> None:
    """The drive as libpanda's CSV, growing: standing at 100 s, at speed at 330 s."""
    frames = drive()
    csv, link = tmp_path / "drive.csv", tmp_path / "currentCan.csv"
    write_csv(csv, between(frames, 0, 100))
    link.symlink_to(csv)
    source = open_source(follow=link)
    try:
        standing = [speed_kmh(m) for m in source.backlog(5.0) if m.arbitration_id == 0xB4]
        assert standing and set(standing) == {0.0}
        with CsvWriter(csv, between(frames, 330, 334), shift=0.0, speed=16.0) as writer:
            assert writer.done.wait(2)
        moving = [s for m in source.backlog(3.0) if (s := speed_kmh(m)) is not None]
        assert moving and all(50 < s < 60 for s in moving)
    finally:
        source.close()


@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_logs_python_can_reads_whole_are_read_but_not_followed(
        tmp_path: Path, suffix: str) -> None:
    frames = [shifted(m, 1000.0) for m in between(drive(), 330, 333)]
    path = tmp_path / f"drive{suffix}"
    with can.Logger(path) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    source = open_source(log=path)
    try:
        assert source.description == f"log {path}"
        got = source.backlog(1.0)
        newest = frames[-1].timestamp
        assert [key(m) for m in got] == [key(m) for m in frames
                                         if m.timestamp >= newest - 1.0 - 1e-5]
        began = time.monotonic()
        assert collect(source, 0.3) == []
        assert 0.3 <= time.monotonic() - began < 0.6
    finally:
        source.close()


def test_a_libpanda_csv_given_as_a_log_is_followed_as_one(tmp_path: Path) -> None:
    frames = between(drive(), 330, 332)
    path = tmp_path / "recording.csv"
    write_csv(path, frames[:50])
    source = open_source(log=path)
    try:
        assert source.description == f"log {path} (libpanda CSV)"
        assert [key(m) for m in source.backlog(100)] == [key(m) for m in frames[:50]]
        with path.open("a") as out:
            out.write("".join(f"{m.timestamp:.6f},0,{m.arbitration_id},"
                              f"{bytes(m.data).hex()},{len(m.data)}\n" for m in frames[50:60]))
        assert [key(m) for m in collect(source, 0.4)] == [key(m) for m in frames[50:60]]
    finally:
        source.close()


def test_a_recording_lpam_may_not_read_is_named_with_what_to_do(tmp_path: Path) -> None:
    path = tmp_path / "currentCan.csv"
    path.write_text(HEADER + "\n")
    path.chmod(0o000)
    code = f"""
        from pathlib import Path
        from reconciler.adapters.can.sources import open_source
        from reconciler.base.errors import VehicleSourceError
        try:
            open_source(follow=Path({str(path)!r}))
        except VehicleSourceError as exc:
            print(exc.render())
    """
    if os.geteuid() != 0:
        done = run_python(code)
    elif shutil.which("setpriv"):  # root reads anything: drop the capabilities that let it
        done = subprocess.run(
            ["setpriv", "--bounding-set=-dac_override,-dac_read_search", PY, "-c",
             textwrap.dedent(code)], cwd=REPO, capture_output=True, text=True, timeout=30,
            check=False)
    else:
        pytest.skip("running as root without setpriv: every file is readable")
    assert done.returncode == 0, done.stderr
    assert f"error: cannot read {path}: permission denied" in done.stdout
    assert "hint: run lpam as a user that may read the recording" in done.stdout
    assert done.stderr == ""


def test_no_traceback_or_log_line_of_python_can_reaches_the_terminal() -> None:
    """python-can logs a warning for every socketcand message a TCP read cuts in two, and
    the traceback of a frame it cannot parse; Python prints those on stderr unless a
    handler takes them. lpam's terminal must show neither."""
    done = run_python("""
        import time
        from reconciler.adapters.can.sources import open_source
        from tests.canlog import drive
        from tests.socketcand import SocketcandServer
        frames = drive()
        with SocketcandServer(frames, offset=330, speed=20.0) as server:
            source = open_source(bus=server.config())
            got = list(source.frames(time.monotonic() + 0.6))
            server.inject("< frame XYZ 1.0 00 >")
            got += list(source.frames(time.monotonic() + 0.3))
            source.close()
        print(len(got))
    """)
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) > 100
    assert done.stderr == ""


def test_importing_the_sources_leaves_python_can_unimported() -> None:
    """Only a gate pays for python-can (about 0.1 s to import); `lpam status` does not."""
    done = run_python("""
        import sys
        import reconciler.adapters.can.sources
        print("can" in sys.modules)
    """)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"
