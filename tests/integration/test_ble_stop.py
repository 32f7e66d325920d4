"""`lpam ble` stopped by SIGTERM (systemd) or SIGINT (Ctrl-C) at any instant leaves BlueZ
clean: the real command on a real private dbus-daemon, with a double of bluetoothd that is
slow to take a registration, so that the signal can land while lpam starts, while each
object is being registered, just after bluetoothd took it but before lpam read the
answer, and while it serves.

What a field engineer checks: after the service is gone, bluetoothd holds neither lpam's
GATT application nor its advertisement (a phone would otherwise still see the car), each
registration it took was unregistered by lpam, the service exited 0, and its log says
"unregistering" only when something was registered, and says it retries, and when, when
there is no bus at all.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.bluez_double import BluezDouble, until
from tests.dbus import needs_dbus_daemon, private_bus

pytestmark = needs_dbus_daemon

PAUSE = 0.4  # the double's pause in each registration: wide enough to land a signal in
KINDS = ("Application", "Advertisement")


@pytest.fixture
def bus(tmp_path: Path) -> Iterator[str]:
    with private_bus(tmp_path) as address:
        yield address


def _default_sigint() -> None:
    """A shell may start the test with SIGINT ignored, which a child inherits: Ctrl-C
    reaches the service with its default action, as from a terminal."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(root: Path, bus: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "reconciler", "--root", str(root), "ble", "--bus", bus],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=dict(os.environ),
        preexec_fn=_default_sigint)


def finish(proc: subprocess.Popen[str]) -> str:
    try:
        out, _ = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()  # by its pid
        out, _ = proc.communicate(timeout=10)
        raise AssertionError(f"lpam ble did not stop: {out}") from None
    return out


def seen(double: BluezDouble, member: str) -> bool:
    return any(event == member for event, _ in double.events)


# when to send the signal: (instant, the double's pause, seconds after the start, then
# a condition on the double); None: stop at once
INSTANTS: list[tuple[str, float, float, Callable[[BluezDouble], bool] | None]] = [
    ("while lpam starts", 0.0, 0.25, None),
    ("while lpam imports", 0.0, 0.6, None),
    ("while bluetoothd reads the application back", PAUSE, 0,
     lambda d: seen(d, "RegisterApplication")),
    ("after bluetoothd took the application, before lpam read the answer", PAUSE, 0,
     lambda d: d.app is not None),
    ("while bluetoothd reads the advertisement back", PAUSE, 0,
     lambda d: seen(d, "RegisterAdvertisement")),
    ("after bluetoothd took the advertisement, before lpam read the answer", PAUSE, 0,
     lambda d: d.advertisement is not None),
    ("just as both are registered", 0.0, 0, lambda d: d.advertisement is not None),
    ("while it serves", 0.0, 0, lambda d: d.advertisement is not None and d.app is not None
     and bool(d.app.objects)),
]


@pytest.mark.parametrize("number", [signal.SIGTERM, signal.SIGINT], ids=["TERM", "INT"])
def test_a_stop_at_any_instant_leaves_bluez_clean(tmp_path: Path, bus: str,
                                                 number: signal.Signals) -> None:
    async def once(instant: str, pause: float, after: float,
                   when: Callable[[BluezDouble], bool] | None) -> None:
        double = BluezDouble(bus, pause=pause)
        await double.start()
        try:
            proc = start(tmp_path / "root", bus)
            try:
                await asyncio.sleep(after)
                if when is not None:
                    await until(lambda: when(double), 30)
                if instant == "while it serves":
                    await asyncio.sleep(0.5)
            finally:
                proc.send_signal(number)
            out = await asyncio.get_running_loop().run_in_executor(None, finish, proc)
            await asyncio.sleep(0.2)  # the last Release and replies reach the double
            where = f"{number.name} {instant}: {double.events}\n{out}"
            # stopped before lpam's own handlers: the signal's default action, or lpam's
            # `interrupted` while it imports; after them: 0, as a service should
            clean = {0} if when is not None else {0, -number, 128 + number}
            assert proc.returncode in clean, where
            assert "Traceback" not in out, where
            assert double.app is None and double.advertisement is None, where
            members = [event for event, _ in double.events]
            for kind in KINDS:  # each registration bluetoothd was asked for was undone
                if f"Register{kind}" in members:
                    assert f"Unregister{kind}" in members[members.index(f"Register{kind}"):], \
                        where
            if any(m.startswith("Register") for m in members):
                assert "stopping: unregistering from BlueZ" in out, where
            else:
                assert "unregister" not in out.lower(), where
        finally:
            await double.stop()

    async def body() -> None:
        for instant in INSTANTS:
            await once(*instant)

    asyncio.run(asyncio.wait_for(body(), 300))


def test_without_a_bus_it_says_it_retries_and_when(tmp_path: Path) -> None:
    """No bus at all (dbus not started yet, a wrong address): one line says what fails,
    that it retries and when; then nothing more until the reason changes; and a stop
    does not claim to unregister what was never registered."""
    proc = start(tmp_path / "root", f"unix:path={tmp_path / 'no-bus.sock'}")
    try:
        asyncio.run(asyncio.sleep(4))  # attempts at 0, 0.5, 1.5, 3.5 s
    finally:
        proc.send_signal(signal.SIGTERM)
    out = finish(proc)
    assert proc.returncode == 0, out
    mode, *lines = out.splitlines()  # the first line says who may change the car
    assert mode.startswith("only a bonded phone may change the car's apps"), out
    assert len(lines) == 2, out
    assert lines[0].startswith(f"cannot connect to unix:path={tmp_path / 'no-bus.sock'}: ")
    assert lines[0].endswith("; retrying in 0.5 s, then at longer intervals up to 10 s; "
                             "said again only when the reason changes"), out
    assert lines[1] == "stopping: nothing was registered with BlueZ"
