"""Who may pair with the car: `lpam ble pair`, `lpam ble phones`, `lpam ble forget`, the
real commands on a real private dbus-daemon with the double of bluetoothd.

What the person at the car checks: the window opens (pairable, discoverable, an agent
that accepts the phone's pairing), closes by itself after the seconds asked or on Ctrl-C,
and leaves the adapter as it found it but not pairable; a phone that tries after it is
refused; the bonded phones are listed and one can be forgotten.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.bluez_double import (
    NOT_PAIRABLE,
    BluezDouble,
    Device,
    PhoneError,
    bond,
    device_path,
    pair_phone,
    until,
)
from tests.dbus import needs_dbus_daemon, private_bus

pytestmark = needs_dbus_daemon

ADAPTER = "/org/bluez/hci0"
PIXEL = "AA:BB:CC:DD:EE:01"
TIMEOUT = 60.0


@pytest.fixture
def bus(tmp_path: Path) -> Iterator[str]:
    with private_bus(tmp_path) as address:
        yield address


def lpam(tmp_path: Path, bus: str, *args: str) -> list[str]:
    return [sys.executable, "-m", "reconciler", "--root", str(tmp_path / "root"), "ble",
            *args, "--bus", bus]


@contextlib.contextmanager
def running(command: list[str]) -> Iterator[subprocess.Popen[str]]:
    """`command` in the background; killed by its pid if it is still running at the end."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=dict(os.environ))
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)


def scenario(body: Callable[[BluezDouble], Any], bus: str,
             setup: Callable[[BluezDouble], None] = lambda d: None) -> None:
    async def run() -> None:
        double = BluezDouble(bus)
        setup(double)
        await double.start()
        try:
            await body(double)
        finally:
            await double.stop()

    asyncio.run(asyncio.wait_for(run(), TIMEOUT))


def sets(double: BluezDouble) -> list[tuple[str, Any]]:
    return [(name, value) for _, name, value in double.adapter_sets]


async def ended(proc: subprocess.Popen[str]) -> tuple[str, str]:
    await until(lambda: proc.poll() is not None, TIMEOUT / 2)
    out, err = proc.communicate(timeout=10)
    return out, err


def opened(seconds: int) -> list[tuple[str, Any]]:
    """The window's Set calls, in order: timeouts first, then pairable and discoverable."""
    return [("PairableTimeout", seconds), ("DiscoverableTimeout", seconds),
            ("Pairable", True), ("Discoverable", True)]


OPENED = opened(3)


def test_pair_opens_a_window_with_an_agent_and_closes_it_after_the_seconds(
        tmp_path: Path, bus: str) -> None:
    async def body(double: BluezDouble) -> None:
        with running(lpam(tmp_path, bus, "pair", "--seconds", "3")) as proc:
            await until(lambda: sets(double) == OPENED, TIMEOUT / 2)
            assert double.agent is not None and double.agent[2] == "NoInputNoOutput"
            assert ("RequestDefaultAgent", double.agent[1]) in double.events
            phone = await pair_phone(double, PIXEL, "Pixel 7")  # the phone's OS prompt
            assert (phone.paired, phone.bonded) == (True, True)
            out, err = await ended(proc)
        assert proc.returncode == 0 and err == "", err
        # closed: not pairable; discoverable and both timeouts as they were before
        assert sets(double) == [*OPENED, ("Pairable", False), ("Discoverable", False),
                                ("DiscoverableTimeout", 180), ("PairableTimeout", 0)]
        opened_at, closed_at = double.adapter_sets[3][0], double.adapter_sets[4][0]
        assert closed_at - opened_at >= 3  # it stayed open the seconds asked for
        assert double.agent is None
        calls = [e for e, _ in double.events]
        assert calls.index("UnregisterAgent") > calls.index("RequestDefaultAgent")
        assert "Paired: AA:BB:CC:DD:EE:01 (Pixel 7)" in out.splitlines(), out
        assert out.splitlines()[-1].startswith("Pairing window closed: the car is not "
                                               "pairable; 1 phone paired"), out
        with pytest.raises(PhoneError, match=NOT_PAIRABLE):  # a stranger, after the window
            await pair_phone(double, "66:55:44:33:22:11", "Stranger")

    scenario(body, bus)


def test_the_agent_accepts_a_just_works_authorization_too(tmp_path: Path, bus: str) -> None:
    async def body(double: BluezDouble) -> None:
        with running(lpam(tmp_path, bus, "pair", "--seconds", "60")) as proc:
            await until(lambda: sets(double) == opened(60), TIMEOUT / 2)
            await pair_phone(double, PIXEL, method="RequestAuthorization")
            proc.send_signal(signal.SIGINT)  # Ctrl-C: the window closes at once
            out, err = await ended(proc)
        assert proc.returncode == 0 and err == "", err  # no traceback
        assert sets(double)[-4:] == [("Pairable", False), ("Discoverable", False),
                                     ("DiscoverableTimeout", 180), ("PairableTimeout", 0)]
        assert double.agent is None
        assert "Pairing window closed early" in out and "Paired: AA:BB:CC:DD:EE:01" in out

    scenario(body, bus)


def test_a_discoverable_car_stays_discoverable_after_the_window(
        tmp_path: Path, bus: str) -> None:
    """bluezone's setup leaves the adapter discoverable (its phones connect through it):
    the window puts that back, and only pairing is closed."""
    def setup(double: BluezDouble) -> None:
        double.adapter_props.update(Discoverable=True, DiscoverableTimeout=0)

    async def body(double: BluezDouble) -> None:
        with running(lpam(tmp_path, bus, "pair", "--seconds", "1")) as proc:
            _, err = await ended(proc)
        assert proc.returncode == 0, err
        assert (double.adapter_props["Pairable"], double.adapter_props["Discoverable"],
                double.adapter_props["DiscoverableTimeout"]) == (False, True, 0)

    scenario(body, bus, setup)


def test_phones_lists_the_bonded_ones_and_forget_removes_one(
        tmp_path: Path, bus: str) -> None:
    def setup(double: BluezDouble) -> None:
        bond(double, device_path(ADAPTER, PIXEL), "Pixel 7")
        bond(double, device_path(ADAPTER, "AA:BB:CC:DD:EE:02"))
        seen = device_path(ADAPTER, "66:55:44:33:22:11")  # seen in a scan, never paired
        double.devices[seen] = Device("66:55:44:33:22:11", "Stranger")

    async def body(double: BluezDouble) -> None:
        loop = asyncio.get_running_loop()

        async def run(*args: str) -> subprocess.CompletedProcess[str]:
            return await loop.run_in_executor(None, lambda: subprocess.run(
                lpam(tmp_path, bus, *args), capture_output=True, text=True, timeout=30,
                check=False))

        listed = await run("phones")
        assert listed.returncode == 0, listed.stderr
        assert [line.split()[:2] for line in listed.stdout.splitlines()] == [
            ["Address", "Name"], [PIXEL, "Pixel"], ["AA:BB:CC:DD:EE:02", "-"]]
        gone = await run("forget", PIXEL.lower())
        assert gone.returncode == 0, gone.stderr
        assert gone.stdout.startswith(f"Forgot {PIXEL} (Pixel 7)")
        assert device_path(ADAPTER, PIXEL) not in double.devices
        unknown = await run("forget", "66:55:44:33:22:11")  # known, but not bonded: kept
        assert unknown.returncode == 1
        assert unknown.stderr.splitlines()[0] == \
            f"error: no phone 66:55:44:33:22:11 is bonded with {ADAPTER}"
        assert device_path(ADAPTER, "66:55:44:33:22:11") in double.devices
        bad = await run("forget", "not-an-address")
        assert (bad.returncode, bad.stderr.splitlines()[0]) == (
            1, "error: 'not-an-address' is not a Bluetooth address")
        assert "Traceback" not in unknown.stderr + bad.stderr

    scenario(body, bus, setup)
