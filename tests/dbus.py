"""A private, real dbus-daemon for tests: the system bus's stand-in, in the test's tmp dir.

lpam's Bluetooth service talks to BlueZ over the system D-Bus. Tests run the reference
daemon (`dbus-daemon`: Debian package `dbus-daemon` since bookworm, `dbus` before) on a
unix socket inside their own directory with a permissive policy (any name owned, any
message sent), so nothing touches this machine's system bus and no root is needed.
`private_bus` yields the bus's address and stops the daemon by its pid when the block ends.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

DBUS_DAEMON = shutil.which("dbus-daemon")
START_TIMEOUT = 10.0
SUN_PATH_MAX = 107  # a unix socket's path must fit sockaddr_un.sun_path

needs_dbus_daemon = pytest.mark.skipif(
    DBUS_DAEMON is None,
    reason="dbus-daemon is not installed (Debian package `dbus-daemon`, `dbus` before "
           "bookworm): the Bluetooth tests need a real private bus")

CONFIG = """<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-Bus Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>system</type>
  <listen>unix:path={socket}</listen>
  <auth>EXTERNAL</auth>
  <policy context="default">
    <allow own="*"/>
    <allow send_destination="*" eavesdrop="true"/>
    <allow receive_sender="*"/>
    <allow eavesdrop="true"/>
  </policy>
</busconfig>
"""


@contextlib.contextmanager
def private_bus(directory: Path) -> Iterator[str]:
    """Run a dbus-daemon listening in `directory`; yield its address."""
    if DBUS_DAEMON is None:
        pytest.skip("dbus-daemon is not installed (Debian package `dbus-daemon`)")
    socket = directory / "bus.sock"
    if len(str(socket)) > SUN_PATH_MAX:
        raise ValueError(f"{socket} is too long for a unix socket")
    config = directory / "bus.conf"
    config.write_text(CONFIG.format(socket=socket), encoding="utf-8")
    proc = subprocess.Popen(
        [DBUS_DAEMON, f"--config-file={config}", "--print-address", "--nofork",
         "--nopidfile"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        yield _address(proc)
    finally:
        _stop(proc)


def _address(proc: subprocess.Popen[bytes]) -> str:
    """The first line the daemon prints: its address, once it accepts connections."""
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT)
    line = os.read(proc.stdout.fileno(), 4096).decode() if ready else ""
    if not line.strip():
        _stop(proc)
        errors = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
        raise RuntimeError(f"dbus-daemon did not start in {START_TIMEOUT} s: {errors}")
    return line.strip().splitlines()[0]


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=5)
    for stream in (proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()
