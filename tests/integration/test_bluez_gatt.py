"""lpam's Bluetooth GATT service against a real dbus-daemon and a double of bluetoothd.

What a field engineer's phone depends on: the service and advertisement Privzone looks for
(the UUIDs, flags and labels of libpanda's bluezone, written out here independently of
reconciler/adapters/bluez/shape.py), each phone's reads and writes reaching lpam with its
own device path, notifications only to a subscriber, and a service that survives
bluetoothd starting late, restarting, and lpam stopping.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
import traceback
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
from dbus_fast import BusType, Message, MessageType, Variant
from dbus_fast.aio import MessageBus

from reconciler.adapters.bluez import Characteristic, GattServer
from schemas.bluetooth import Writes
from tests.bluez_double import NOT_PAIRED, BluezDouble, PhoneError, bond, until
from tests.dbus import needs_dbus_daemon, private_bus

pytestmark = needs_dbus_daemon

SERVICE = "00000001-4d3d-3d3d-3d3d-3d3d3d3d3d3d"
# uuid: (flags, descriptor uuid, descriptor text), as bluezone.py declares them
BLUEZONE = {
    "00000002-710e-4a5b-8d75-3e5b444bc3cf": (["notify", "read"], "2906", "CPU Temperature"),
    "00000003-710e-4a5b-8d75-3e5b444bc3cf": (["read", "write"], "2903",
                                             "Temperature Units (F or C)"),
    "00000002-4d3d-3d3d-3d3d-3d3d3d3d3d3d": (["notify", "read"], "2910",
                                             "CIRCLES Output descriptor"),
    "00000005-4d3d-3d3d-3d3d-3d3d3d3d3d3d": (["write"], "2905", "Circles Input"),
    "00000003-4d3d-3d3d-3d3d-3d3d3d3d3d3d": (["read", "write"], "2904", "Circles Command"),
    "00000004-4d3d-3d3d-3d3d-3d3d3d3d3d3d": (["read", "write"], "2904", "Circles Config"),
    "00000006-4d3d-3d3d-3d3d-3d3d3d3d3d3d": (["notify", "read"], "2906", "Circles Status"),
}
OUTPUT, COMMAND, CONFIG, INPUT, STATUS = (
    f"0000000{n}-4d3d-3d3d-3d3d-3d3d3d3d3d3d" for n in (2, 3, 4, 5, 6))
PHONE_A = "/org/bluez/hci0/dev_AA_BB_CC_DD_EE_01"
PHONE_B = "/org/bluez/hci0/dev_AA_BB_CC_DD_EE_02"
STRANGER = "/org/bluez/hci0/dev_66_55_44_33_22_11"  # in range, never paired with the car
SCENARIO_TIMEOUT = 30.0
CHANGING = {"00000003-710e-4a5b-8d75-3e5b444bc3cf", INPUT, COMMAND, CONFIG}
"""The characteristics a phone writes to change the car (bluezone's `write` flag)."""
OPEN_TREE = Path(__file__).parent.parent / "fixtures" / "ble" / "gatt-tree-open.hex"
"""The GetManagedObjects answer lpam registered before writes needed a bonded phone
(recorded from main at 803df38 with dbus-fast's marshaller): `--writes open` gives it."""


class Recorder:
    """A GattHandler that answers `<NAME> for <device>` and records every call."""

    def __init__(self) -> None:
        self.reads: list[tuple[Characteristic, str | None]] = []
        self.writes: list[tuple[Characteristic, bytes, str | None]] = []
        self.subscriptions: list[tuple[Characteristic, bool]] = []
        self.fail_writes = False
        self.read_time = 0.0  # seconds a read blocks the loop

    def read(self, char: Characteristic, device: str | None) -> bytes:
        self.reads.append((char, device))
        time.sleep(self.read_time)
        return f"{char.name} for {device}".encode()

    def write(self, char: Characteristic, value: bytes, device: str | None) -> None:
        if self.fail_writes:
            raise ValueError("the queue is full")
        self.writes.append((char, value, device))

    def subscribed(self, char: Characteristic, on: bool) -> None:
        self.subscriptions.append((char, on))


@pytest.fixture
def bus(tmp_path: Path) -> Any:
    with private_bus(tmp_path) as address:
        yield address


def scenario(body: Callable[[], Awaitable[None]]) -> None:
    asyncio.run(asyncio.wait_for(body(), SCENARIO_TIMEOUT))


@contextlib.asynccontextmanager
async def serving(server: GattServer) -> AsyncIterator[asyncio.Task[None]]:
    """`server.run` in a task; stopped (and awaited, bounded) when the block ends."""
    stop = asyncio.Event()
    task = asyncio.ensure_future(server.run(stop))
    try:
        yield task
    finally:
        stop.set()
        await asyncio.wait_for(task, 10)


@contextlib.asynccontextmanager
async def bluetoothd(address: str, **kwargs: Any) -> AsyncIterator[BluezDouble]:
    double = BluezDouble(address, **kwargs)
    await double.start()
    try:
        yield double
    finally:
        await double.stop()


@contextlib.asynccontextmanager
async def served(bus: str, handler: Recorder | None = None,
                 log: Callable[[str], None] = print,
                 bug: Callable[[], str] = lambda: "nowhere",
                 writes: Writes = Writes.BONDED) -> AsyncIterator[BluezDouble]:
    """bluetoothd on `bus` with lpam's server registered: the double, acting as phones
    (PHONE_A and PHONE_B bonded with the car)."""
    server = GattServer(handler or Recorder(), bus_address=bus, log=log, bug=bug,
                        writes=writes)
    async with bluetoothd(bus) as double, serving(server):
        bond(double, PHONE_A)
        bond(double, PHONE_B)
        await double.registered()
        yield double


def test_registers_the_service_and_advertisement_privzone_looks_for(bus: str) -> None:
    async def body() -> None:
        async with served(bus) as double:
            assert double.app is not None and double.advertisement is not None
            objects = double.app.objects
            services = [p["org.bluez.GattService1"] for p in objects.values()
                        if "org.bluez.GattService1" in p]
            assert [(s["UUID"], s["Primary"]) for s in services] == [(SERVICE, True)]
            chars = {p["org.bluez.GattCharacteristic1"]["UUID"]: p["org.bluez.GattCharacteristic1"]
                     for p in objects.values() if "org.bluez.GattCharacteristic1" in p}
            assert sorted(chars) == sorted(BLUEZONE)
            for uuid, (flags, descriptor_uuid, text) in BLUEZONE.items():
                # every write asks for an encrypted link (a bonded phone); reads stay open
                asked = ["encrypt-write" if f == "write" else f for f in flags]
                assert chars[uuid]["Flags"] == asked, uuid
                descriptor = objects[double.descriptor_of(uuid)]["org.bluez.GattDescriptor1"]
                assert (descriptor["UUID"], descriptor["Flags"]) == (descriptor_uuid, ["read"])
                assert await double.read_descriptor(uuid) == text.encode()
            service_path = next(p for p, i in objects.items() if "org.bluez.GattService1" in i)
            assert sorted(services[0]["Characteristics"]) == sorted(
                double.path_of(u) for u in BLUEZONE)
            assert {c["Service"] for c in chars.values()} == {service_path}
            advertisement = double.advertisement.objects[double.advertisement.path]
            assert advertisement["org.bluez.LEAdvertisement1"] == {
                "Type": "broadcast", "LocalName": "CIRCLES", "ServiceUUIDs": [SERVICE],
                "IncludeTxPower": True}

    scenario(body)


def test_every_characteristic_that_changes_the_car_asks_for_encryption(bus: str) -> None:
    async def body() -> None:
        async with served(bus) as double:
            assert double.app is not None
            flags = {p["org.bluez.GattCharacteristic1"]["UUID"]:
                     set(p["org.bluez.GattCharacteristic1"]["Flags"])
                     for p in double.app.objects.values()
                     if "org.bluez.GattCharacteristic1" in p}
            assert {u for u, f in flags.items() if "encrypt-write" in f} == CHANGING
            assert not any("write" in f for f in flags.values())  # no plain write left
            assert {u for u, f in flags.items() if "read" in f} == {
                u for u, (f, _, _) in BLUEZONE.items() if "read" in f}  # reads stay open
            # and no phone pairs outside `lpam ble pair`'s window
            await until(lambda: double.adapter_props["Pairable"] is False, 5)

    scenario(body)


def test_writes_open_registers_bluezones_tree_byte_for_byte(bus: str) -> None:
    from dbus_fast._private.marshaller import Marshaller

    async def body() -> None:
        async with served(bus, writes=Writes.OPEN) as double:
            assert double.app is not None
            sent = bytes(Marshaller("a{oa{sa{sv}}}", [double.app.raw]).marshall())
            assert sent.hex() == "".join(OPEN_TREE.read_text().split())

    scenario(body)


def test_an_unbonded_phones_write_is_refused_by_bluez_and_never_reaches_lpam(
        bus: str) -> None:
    handler = Recorder()

    async def body() -> None:
        async with served(bus, handler) as double:
            for uuid in sorted(CHANGING):
                with pytest.raises(PhoneError, match=NOT_PAIRED):
                    await double.write(uuid, b"A", STRANGER)
            assert await double.read(CONFIG, STRANGER) == f"CONFIG for {STRANGER}".encode()
            await double.write(COMMAND, b"A", PHONE_A)  # a bonded phone: as before
            assert sorted(double.refused) == sorted((u, STRANGER) for u in CHANGING)
        assert handler.writes == [(Characteristic.COMMAND, b"A", PHONE_A)]

    scenario(body)


def test_writes_open_lets_any_phone_write_as_bluezone_did(bus: str) -> None:
    handler = Recorder()

    async def body() -> None:
        async with served(bus, handler, writes=Writes.OPEN) as double:
            await double.write(COMMAND, b"A", STRANGER)
            assert double.refused == []
            assert ("Set", "org.bluez.Adapter1") not in double.events  # pairable as it was
        assert handler.writes == [(Characteristic.COMMAND, b"A", STRANGER)]

    scenario(body)


def test_each_phones_reads_and_writes_reach_lpam_with_its_device(bus: str) -> None:
    handler = Recorder()
    lines: list[str] = []
    bugs: list[str] = []

    def bug() -> str:  # what lpam ble gives: the traceback goes to lpam's debug log
        bugs.append(traceback.format_exc())
        return "debug.log"

    async def body() -> None:
        async with served(bus, handler, log=lines.append, bug=bug) as double:
            await double.write(INPUT, b'{"type": "app_update"', PHONE_A)
            await double.write(COMMAND, b"A", PHONE_B)
            assert await double.read(CONFIG, PHONE_A) == f"CONFIG for {PHONE_A}".encode()
            assert await double.read(CONFIG, PHONE_B, offset=7) == f"for {PHONE_B}".encode()
            with pytest.raises(PhoneError, match="NotPermitted"):
                await double.write(OUTPUT, b"x", PHONE_A)  # notify/read only
            with pytest.raises(PhoneError, match="NotPermitted"):
                await double.read(INPUT, PHONE_A)  # write only
            handler.fail_writes = True
            with pytest.raises(PhoneError, match=r"org\.bluez\.Error\.Failed"):
                await double.write(INPUT, b"}", PHONE_A)
            handler.fail_writes = False
            await double.write(INPUT, b"}", PHONE_B)  # the service lived through it
        assert handler.writes == [
            (Characteristic.INPUT, b'{"type": "app_update"', PHONE_A),
            (Characteristic.COMMAND, b"A", PHONE_B),
            (Characteristic.INPUT, b"}", PHONE_B)]
        assert handler.reads == [(Characteristic.CONFIG, PHONE_A),
                                 (Characteristic.CONFIG, PHONE_B)]
        assert len(bugs) == 1 and "the queue is full" in bugs[0]  # the fault, traced
        assert any("(details in debug.log)" in line for line in lines), lines

    scenario(body)


def test_notifications_go_only_to_a_subscribed_phone(bus: str) -> None:
    handler = Recorder()

    async def body() -> None:
        server = GattServer(handler, bus_address=bus)
        async with bluetoothd(bus) as double, serving(server):
            await double.registered()
            assert server.notify(Characteristic.STATUS, b"before") is False
            await double.sync()
            assert double.notifications == {}
            await double.start_notify(STATUS)
            await double.start_notify(OUTPUT)
            assert server.notify(Characteristic.STATUS, b"App command success!") is True
            sender = threading.Thread(target=server.notify_threadsafe,
                                      args=(Characteristic.OUTPUT, b'{"type": "app_info"'))
            sender.start()
            sender.join()
            await until(lambda: OUTPUT in double.notifications, 5)
            await double.stop_notify(STATUS)
            assert server.notify(Characteristic.STATUS, b"after") is False
            await double.sync()
            assert double.notifications == {STATUS: [b"App command success!"],
                                            OUTPUT: [b'{"type": "app_info"']}
        assert handler.subscriptions[:3] == [(Characteristic.STATUS, True),
                                             (Characteristic.OUTPUT, True),
                                             (Characteristic.STATUS, False)]

    scenario(body)


def test_registers_again_when_bluetoothd_restarts(bus: str) -> None:
    handler = Recorder()
    lines: list[str] = []

    async def body() -> None:
        async with served(bus, handler, lines.append) as double:
            await double.start_notify(STATUS)
            first = double.app
            await double.restart()
            assert double.app is None  # the new bluetoothd knows nothing
            await double.registered(timeout=5)
            assert double.app is not first
            assert [e for e, _ in double.events].count("RegisterApplication") == 2
            assert [e for e, _ in double.events].count("RegisterAdvertisement") == 2
            assert await double.read(CONFIG, PHONE_A) == f"CONFIG for {PHONE_A}".encode()
            # the old bluetoothd's subscription died with it: nobody listens any more
            assert handler.subscriptions == [(Characteristic.STATUS, True),
                                             (Characteristic.STATUS, False)]
        assert "bluetoothd left the system bus" in lines

    scenario(body)


def test_stop_unregisters_both_and_leaves_the_bus(bus: str) -> None:
    async def body() -> None:
        async with bluetoothd(bus) as double:
            async with serving(GattServer(Recorder(), bus_address=bus)) as task:
                await double.registered()
                app_path = double.app.path if double.app else ""
                ad_path = double.advertisement.path if double.advertisement else ""
            assert task.done() and task.exception() is None
            assert ("UnregisterApplication", app_path) in double.events
            assert ("UnregisterAdvertisement", ad_path) in double.events
            assert double.app is None and double.advertisement is None

    scenario(body)


def test_the_system_bus_comes_from_dbus_system_bus_address(
        bus: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DBUS_SYSTEM_BUS_ADDRESS", bus)

    async def body() -> None:
        async with bluetoothd(bus) as double, serving(GattServer(Recorder())):
            await double.registered()

    scenario(body)


def test_waits_for_bluetoothd_then_registers(bus: str) -> None:
    lines: list[str] = []

    async def body() -> None:
        async with serving(GattServer(Recorder(), bus_address=bus, log=lines.append)):
            await asyncio.sleep(2)  # retries at 0.5, 1, 2 s: the reason is logged once
            assert lines == ["cannot register the GATT application on /org/bluez/hci0: "
                             "bluetoothd is not running (nobody owns org.bluez on the "
                             "system bus); retrying in 0.5 s, then at longer intervals up "
                             "to 10 s; said again only when the reason changes"]
            async with bluetoothd(bus) as double:
                await double.registered(timeout=3)

    scenario(body)


def test_a_missing_adapter_is_reported_and_retried(bus: str) -> None:
    lines: list[str] = []

    async def body() -> None:
        async with bluetoothd(bus, adapter="/org/bluez/hci1") as double, serving(
                GattServer(Recorder(), bus_address=bus, log=lines.append)):
            await until(lambda: len(double.events) >= 2, 5)  # tried, waited, tried again
            assert double.app is None
            assert [ln for ln in lines if "hci0" in ln] == [
                "cannot register the GATT application on /org/bluez/hci0: bluetoothd has "
                "no adapter /org/bluez/hci0 (is the controller up?); retrying in 0.5 s, "
                "then at longer intervals up to 10 s; said again only when the reason "
                "changes"]

    scenario(body)


def test_only_bluetoothd_may_pose_as_a_phone(bus: str) -> None:
    """A write can make lpam change the car's apps: another process on the system bus
    calling the characteristic directly is refused and lpam hears nothing of it."""
    handler = Recorder()

    async def body() -> None:
        async with served(bus, handler) as double:
            assert double.app is not None
            stranger = await MessageBus(bus_address=bus, bus_type=BusType.SYSTEM).connect()
            try:
                reply = await stranger.call(Message(
                    destination=double.app.sender, path=double.path_of(INPUT),
                    interface="org.bluez.GattCharacteristic1", member="WriteValue",
                    signature="aya{sv}", body=[b'{"type": "app_enable"}',
                                               {"device": Variant("o", PHONE_A)}]))
            finally:
                stranger.disconnect()
            assert reply is not None and reply.message_type is MessageType.ERROR
            assert reply.error_name == "org.freedesktop.DBus.Error.AccessDenied"
            await double.write(INPUT, b"{}", PHONE_B)
        assert handler.writes == [(Characteristic.INPUT, b"{}", PHONE_B)]

    scenario(body)


def test_an_advertisement_bluetoothd_released_is_registered_again(bus: str) -> None:
    async def body() -> None:
        async with served(bus) as double:
            await double.release_advertisement()
            await double.registered(timeout=3)
            assert [e for e, _ in double.events if e.startswith("Register")] == [
                "RegisterApplication", "RegisterAdvertisement", "RegisterAdvertisement"]

    scenario(body)


def test_a_release_right_behind_the_registrations_answer_is_not_lost(bus: str) -> None:
    """bluetoothd answers the registration and releases the advertisement in the next
    message (the adapter powered off): lpam registers it again, not believing it held."""
    async def body() -> None:
        async with bluetoothd(bus) as double:
            double.release_at_once = 1
            async with serving(GattServer(Recorder(), bus_address=bus, log=print)):
                await until(lambda: double.release_at_once == 0, 5)
                await double.registered(timeout=5)
                assert [e for e, _ in double.events if e == "RegisterAdvertisement"] == [
                    "RegisterAdvertisement"] * 2

    scenario(body)


def test_survives_the_system_bus_restarting(tmp_path: Path) -> None:
    """A bus, then none, then a new one on the same socket: lpam is registered with the
    bluetoothd of each bus in turn."""
    lines: list[str] = []
    address = f"unix:path={tmp_path / 'bus.sock'}"

    async def body() -> None:
        async with serving(GattServer(Recorder(), bus_address=address, log=lines.append)):
            for _ in range(2):
                said = len(lines)
                with private_bus(tmp_path):
                    async with bluetoothd(address) as double:
                        await double.registered(timeout=5)
                # said once the bus went away (a retry to connect may be said right after)
                await until(lambda said=said: any(  # type: ignore[misc]
                    line.startswith("the system bus connection was lost")
                    for line in lines[said:]), 5)

    scenario(body)


def test_a_handler_that_holds_the_loop_is_reported(bus: str) -> None:
    """While a handler runs no other phone is served: the journal says which one lingered."""
    handler = Recorder()
    lines: list[str] = []

    async def body() -> None:
        async with served(bus, handler, lines.append) as double:
            await double.read(CONFIG, PHONE_A)
            handler.read_time = 0.2
            await double.read(CONFIG, PHONE_A)
        held = [ln for ln in lines if "held the bus" in ln]
        assert len(held) == 1 and held[0].startswith("the config read held the bus for 0.2")

    scenario(body)
