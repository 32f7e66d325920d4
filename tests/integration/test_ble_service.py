"""`lpam ble` end to end: the real command on a real private dbus-daemon, a double of
bluetoothd standing in for the phones, app repositories served by a real `git daemon`
(the desired state's `mirrors:` sends https://github.com/ to it) and apps under a real
supervisord.

What a field engineer checks from the phone: the app list; a switch of the app that
takes 25 s while temperatures keep coming (the phone shows the car as disconnected after
20 s without one); a repository added and removed; hostile and malformed input answered
with an error text that changes nothing; an apply already running answered at once; and
the service leaving BlueZ cleanly on SIGTERM.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from reconciler.base.layout import Layout
from reconciler.engine.execution.lock import apply_lock
from tests.bluez_double import NOT_PAIRED, BluezDouble, PhoneError, bond, until
from tests.dbus import needs_dbus_daemon, private_bus
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import TICKER, FieldCar, Lpam, applied, field_repos
from tests.privzone_client import TEMPERATURE, Phone

pytestmark = needs_dbus_daemon

PHONE_A = "/org/bluez/hci0/dev_AA_BB_CC_DD_EE_01"
PHONE_B = "/org/bluez/hci0/dev_AA_BB_CC_DD_EE_02"
STRANGER = "/org/bluez/hci0/dev_66_55_44_33_22_11"  # in range, never paired with the car
INSTALL_SECONDS = 25
SCRIPT = """#!/usr/bin/env bash
echo "$LPAM_APP:{name}" >> "$LPAM_ROOT/events.log"
{extra}
"""
CATALOG = """\
apps:
  - name: ticker
    command: [python3, -u, run.py]
    health: {settle_seconds: 0.5}
  - name: slow
"""


@pytest.fixture
def car(tmp_path: Path, git_daemon: GitDaemon, make_repo: Callable[[str], RepoBuilder]
        ) -> Iterator[FieldCar]:
    slow = {f"slow/{name}.sh": SCRIPT.format(
        name=name, extra=f"sleep {INSTALL_SECONDS}" if name == "install" else "")
        for name in ("install", "uninstall", "start", "stop")}
    field_repos(make_repo, CATALOG, {
        "ticker/run.py": TICKER, "ticker/description.txt": "ticks (°C → CAN)\n",
        **slow, "slow/description.txt": "installs slowly\n"})
    car = FieldCar(tmp_path / "root")
    zone = car.root / "sys/class/thermal/thermal_zone0/temp"
    zone.parent.mkdir(parents=True)
    zone.write_text("48312\n")
    with applied(car, git_daemon.port):
        yield car


@pytest.fixture
def bus(tmp_path: Path) -> Iterator[str]:
    with private_bus(tmp_path) as address:
        yield address


@contextlib.contextmanager
def ble(car: FieldCar | Lpam, bus: str, *options: str) -> Iterator[subprocess.Popen[str]]:
    """`lpam ble` on the private bus; SIGTERM by its pid when the block ends (if alive)."""
    log = open(car.root / "ble.log", "w")  # noqa: SIM115 - closed below
    proc = subprocess.Popen(
        [sys.executable, "-m", "reconciler", "--root", str(car.root), "ble", "--bus", bus,
         *options],
        stdout=log, stderr=subprocess.STDOUT, text=True, env=dict(os.environ))
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
        log.close()


def scenario(body: Callable[[], Any], timeout: float = 150) -> None:
    asyncio.run(asyncio.wait_for(body(), timeout))


@contextlib.asynccontextmanager
async def phones(bus: str) -> AsyncIterator[BluezDouble]:
    """bluetoothd with PHONE_A and PHONE_B bonded with the car (`lpam ble pair` did it)."""
    double = BluezDouble(bus)
    bond(double, PHONE_A)
    bond(double, PHONE_B)
    await double.start()
    try:
        await double.registered(timeout=30)
        yield double
    finally:
        await double.stop()


def rows(message: tuple[str, Any]) -> dict[str, dict[str, str]]:
    kind, contents = message
    assert kind == "app_info"
    return {row["app"]: row for row in contents}


def test_a_phone_checks_switches_through_a_long_install_and_edits_repositories(
    car: FieldCar, bus: str,
) -> None:
    async def body() -> None:
        async with phones(bus) as double:
            phone = Phone(double, PHONE_A)
            await phone.connect()
            assert await phone.next_status(0, 10) == "Hello from the Pi!"
            await until(lambda: len(phone.notified(TEMPERATURE)) >= 2, 10)
            assert phone.notified(TEMPERATURE)[-1] == b"119.0 F"  # 48.312 C as bluezone
            await phone.command("A")
            listed = rows(await phone.next_message(0, 20))
            assert set(listed) == {"ticker", "slow"}
            assert listed["ticker"] == {
                "repository": "fleet/apps", "branch": "main", "app": "ticker",
                "service": listed["ticker"]["service"], "enabled": "yes", "running": "yes",
                "description": "ticks (°C → CAN)"}
            assert (listed["slow"]["enabled"], listed["slow"]["running"]) == ("no", "no")
            assert listed["ticker"]["service"] == "lpam-app-ticker"
            assert listed["slow"]["service"] == "none"  # no `service` file: said, not blank

            loop = asyncio.get_running_loop()
            times: list[float] = []
            seen = len(phone.notified(TEMPERATURE))

            async def watch() -> None:
                nonlocal seen
                while True:
                    now = len(phone.notified(TEMPERATURE))
                    times.extend([loop.time()] * (now - seen))
                    seen = now
                    await asyncio.sleep(0.05)

            watcher = asyncio.ensure_future(watch())
            started = loop.time()
            await phone.send("app_enable", {"app": "slow"})
            said = await phone.next_status(1, INSTALL_SECONDS + 60)
            took = loop.time() - started
            watcher.cancel()
            assert said == "App command success!", said
            assert took >= INSTALL_SECONDS  # the install really ran
            gaps = [b - a for a, b in zip([started, *times], [*times, loop.time()])]
            assert max(gaps) < 20, gaps  # the phone never saw the car as disconnected
            assert len(times) >= INSTALL_SECONDS // 2, times
            assert car.app()["name"] == "slow" and "name: slow" in car.desired.read_text()

            await phone.send("app_add_repository", {"repository": "extra/tools",
                                                    "branch": "dev"})
            assert await phone.next_status(2, 60) == "Repository updated!"
            assert "extra/tools" in car.desired.read_text()
            await phone.command("A")
            assert "gadget" in rows(await phone.next_message(1, 20))
            await phone.send("app_remove_repository", {"repository": "extra/tools"})
            assert await phone.next_status(3, 60) == "Repository removed!"
            assert "extra/tools" not in car.desired.read_text()
            assert "# The car's apps; edited by libpanda-app-manager and the phone." in \
                car.desired.read_text()

    with ble(car, bus):
        scenario(body)


HOSTILE: list[tuple[str, Any, str]] = [
    ("app_enable", {"app": "x; reboot"}, "Error enabling app"),
    ("app_enable", {"app": "--upload-pack=touch /tmp/pwned"}, "Error enabling app"),
    ("app_enable", {"app": "nope"}, "Error enabling app nope"),
    ("app_add_repository", {"repository": "extra/tools", "branch": "no-such-branch"},
     "Error adding repository"),
    ("app_add_repository", {"repository": "fleet/apps; rm -rf /", "branch": "main"},
     "Error adding repository"),
    ("app_remove_repository", {"repository": "fleet/apps"}, "Error removing repository"),
    ("wifi_add", {"ssid": "x", "password": "y"}, "Not served"),
    ("no_such_type", {}, "Unregognized type"),
]


def test_hostile_and_malformed_input_changes_nothing(car: FieldCar, bus: str) -> None:
    before = car.desired.read_bytes()
    pid = car.app()["unit"]["pid"]

    async def body() -> None:
        async with phones(bus) as double:
            phone = Phone(double, PHONE_A)
            await phone.connect()
            seen = 1  # Hello
            await phone.next_status(0, 10)
            for kind, contents, expected in HOSTILE:
                await phone.send(kind, contents)
                said = await phone.next_status(seen, 60)
                seen += 1
                assert said.startswith(expected), (kind, contents, said)
            for raw in (b'{"type": "app_enable", "contents": ', b"\xff\xfe not utf-8",
                        b'{"contents": "{}", "length": 2}', b"[1, 2]"):
                await double.write(INPUT_UUID, raw, PHONE_A)
                await double.write(INPUT_UUID, b"\x00", PHONE_A)
                said = await phone.next_status(seen, 10)
                seen += 1
                assert said not in SUCCESS, (raw, said)
            await phone.command("Z")
            assert (await phone.next_status(seen, 10)).startswith("Unknown command")

    with ble(car, bus):
        scenario(body)
    assert car.desired.read_bytes() == before
    app = car.app()
    assert app["name"] == "ticker" and app["unit"]["pid"] == pid and app["running"]
    assert not Path("/tmp/pwned").exists()


INPUT_UUID = "00000005-4d3d-3d3d-3d3d-3d3d3d3d3d3d"
SUCCESS = {"App command success!", "Repository updated!", "Repository removed!",
           "App updated!"}


def test_an_apply_already_running_is_an_error_text_at_once(car: FieldCar, bus: str) -> None:
    async def body() -> None:
        async with phones(bus) as double:
            phone = Phone(double, PHONE_A)
            await phone.connect()
            await phone.next_status(0, 10)
            with apply_lock(Layout(car.root), timeout=5):
                await phone.send("app_enable", {"app": "slow"})
                said = await phone.next_status(1, 20)
                temperatures = len(phone.notified(TEMPERATURE))
                await until(lambda: len(phone.notified(TEMPERATURE)) > temperatures, 5)
            assert said.startswith("Error enabling app slow:") and "apply" in said, said

    with ble(car, bus):
        scenario(body)
    assert car.app()["name"] == "ticker"


def test_two_phones_at_once_keep_their_own_messages(car: FieldCar, bus: str) -> None:
    async def body() -> None:
        async with phones(bus) as double:
            a, b = Phone(double, PHONE_A), Phone(double, PHONE_B)
            await a.connect()
            await a.next_status(0, 10)
            # phone A's message arrives in two pieces with phone B's whole message between
            inner = json.dumps({"app": "ticker", "params": {"RATE": "5"}})
            text = json.dumps({"type": "app_params", "contents": inner,
                               "length": len(inner)})
            await double.write(INPUT_UUID, text[:30].encode(), PHONE_A)
            await b.send("app_summary", {})
            await double.write(INPUT_UUID, text[30:].encode(), PHONE_A)
            await double.write(INPUT_UUID, b"\x00", PHONE_A)
            kind, summary = await a.next_message(0, 30)
            assert kind == "app_summary" and summary["app"] == "ticker"
            assert summary["apps"] == "ticker running"  # every installed app
            assert await a.next_status(1, 60) == "App command success!"

    with ble(car, bus):
        scenario(body)
    assert car.app()["params"] == {"RATE": "5"}


def test_sigterm_unregisters_and_exits_0(car: FieldCar, bus: str) -> None:
    async def body(proc: subprocess.Popen[str]) -> None:
        async with phones(bus) as double:
            proc.send_signal(signal.SIGTERM)
            await until(lambda: double.app is None and double.advertisement is None, 20)
            await until(lambda: proc.poll() is not None, 30)
            assert ("UnregisterApplication", double.events[-2][1]) in double.events or \
                any(e[0] == "UnregisterApplication" for e in double.events)

    with ble(car, bus) as proc:
        scenario(lambda: body(proc))
        assert proc.returncode == 0, (car.root / "ble.log").read_text()


def test_a_phone_that_never_paired_changes_nothing_and_status_says_bonded_only(
        car: FieldCar, bus: str) -> None:
    """The default: a stranger's phone in range of the parked car can read the car, not
    change it; BlueZ refuses its write before lpam hears of it. `lpam status` says so."""
    before = car.desired.read_bytes()
    record = (car.root / "var/lib/lpam/state.json").read_bytes()

    async def body() -> None:
        async with phones(bus) as double:
            stranger = Phone(double, STRANGER)
            await stranger.connect()
            assert await stranger.next_status(0, 10) == "Hello from the Pi!"
            with pytest.raises(PhoneError, match=NOT_PAIRED):
                await stranger.send("app_enable", {"app": "slow"})
            with pytest.raises(PhoneError, match=NOT_PAIRED):
                await stranger.command("As")
            shown = car.lpam.status()["bluetooth"]
            assert (shown["writes"], shown["adapter"]) == ("bonded", "/org/bluez/hci0")
            table = car.lpam("status").stdout
            assert "only a bonded phone may change the car's apps" in table, table
            owner = Phone(double, PHONE_A)  # a bonded phone: as before
            await owner.command("A")
            assert "slow" in rows(await owner.next_message(0, 20))

    with ble(car, bus):
        scenario(body)
    assert car.desired.read_bytes() == before
    assert (car.root / "var/lib/lpam/state.json").read_bytes() == record
    app = car.app()
    assert app["name"] == "ticker" and app["running"]
    assert car.lpam.status()["bluetooth"] is None  # lpam ble stopped: no mode to tell
    assert "Bluetooth" not in car.lpam("status").stdout


def test_writes_open_lets_any_phone_change_the_car_and_status_says_so(
        car: FieldCar, bus: str) -> None:
    async def body() -> None:
        async with phones(bus) as double:
            stranger = Phone(double, STRANGER)
            await stranger.connect()
            await stranger.next_status(0, 10)
            await stranger.command("A")
            assert "slow" in rows(await stranger.next_message(0, 20))
            assert double.refused == []
            assert car.lpam.status()["bluetooth"]["writes"] == "open"
            assert "writes are OPEN: any phone in range" in car.lpam("status").stdout

    with ble(car, bus, "--writes", "open"):
        scenario(body)
