"""A test double of bluetoothd on a private bus, and the phone it stands for.

It owns `org.bluez` and exports the adapter object (`/org/bluez/hci0`) with the two
managers lpam registers with, doing what BlueZ does (doc/org.bluez.GattManager.rst,
org.bluez.LEAdvertisingManager.rst): `RegisterApplication` reads the caller's tree with
`GetManagedObjects` before it answers, and refuses one its GATT database would not take
(`tree_fault`); `RegisterAdvertisement` reads the advertisement's properties with
`GetAll`; a second registration of the same object is `AlreadyExists`;
`UnregisterAdvertisement` calls the advertisement's `Release`. It then acts as a phone the
way bluetoothd relays one: `ReadValue`/`WriteValue` with the phone's device path in the
options, `StartNotify`, and the `PropertiesChanged` notifications collected per
characteristic UUID. `restart` drops the connection and comes back as a new bluetoothd
that has forgotten every registration, as `systemctl restart bluetooth` would.
The phones it knows (`devices`) have device objects whose `org.bluez.Device1` properties
(Address, Name, Alias) it serves as BlueZ does.
`pause` makes it a busy bluetoothd: it takes that long before reading a registration's
objects back, and again between taking the registration and answering, so that a test can
stop lpam inside either window.
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from dbus_fast import BusType, Message, MessageFlag, MessageType, NameFlag, Variant
from dbus_fast.aio import MessageBus

BLUEZ = "org.bluez"
GATT_MANAGER = "org.bluez.GattManager1"
ADVERTISING_MANAGER = "org.bluez.LEAdvertisingManager1"
CHARACTERISTIC = "org.bluez.GattCharacteristic1"
DESCRIPTOR = "org.bluez.GattDescriptor1"
ADVERTISEMENT = "org.bluez.LEAdvertisement1"
SERVICE = "org.bluez.GattService1"
DEVICE = "org.bluez.Device1"
# the flags bluetoothd's gatt-database.c parses (doc/org.bluez.GattCharacteristic.rst)
CHAR_FLAGS = {"broadcast", "read", "write-without-response", "write", "notify", "indicate",
              "authenticated-signed-writes", "extended-properties", "reliable-write",
              "writable-auxiliaries", "encrypt-read", "encrypt-write",
              "encrypt-authenticated-read", "encrypt-authenticated-write",
              "secure-read", "secure-write", "authorize"}
DESC_FLAGS = {"read", "write", "encrypt-read", "encrypt-write", "encrypt-authenticated-read",
              "encrypt-authenticated-write", "secure-read", "secure-write", "authorize"}
PROPERTIES = "org.freedesktop.DBus.Properties"
NOTIFICATIONS = f"type='signal',interface='{PROPERTIES}',member='PropertiesChanged'"
WAIT = 10.0  # the longest any helper waits for an answer


class PhoneError(Exception):
    """bluetoothd relayed an error reply to the phone: its D-Bus error name."""


@dataclass
class Registration:
    """What the double learnt from a registration: who, where, and what it read back."""

    sender: str
    path: str
    objects: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)


def plain(value: Any) -> Any:
    """`value` with every Variant unwrapped, for assertions."""
    if isinstance(value, Variant):
        return plain(value.value)
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


class BluezDouble:
    """bluetoothd for one adapter, on the bus at `address`."""

    def __init__(self, address: str, adapter: str = "/org/bluez/hci0", *,
                 pause: float = 0.0) -> None:
        self.address = address
        self.adapter = adapter
        self.pause = pause  # seconds, before reading back and before answering
        self.bus: MessageBus | None = None
        self.app: Registration | None = None
        self.advertisement: Registration | None = None
        self.events: list[tuple[str, str]] = []  # (method, object path) of every call
        self.notifications: dict[str, list[bytes]] = {}
        self._tasks: set[asyncio.Future[Any]] = set()
        self.devices: dict[str, dict[str, str]] = {}  # see `_device_call`

    async def start(self) -> None:
        bus = await MessageBus(bus_address=self.address, bus_type=BusType.SYSTEM).connect()
        bus.add_message_handler(self._on_message)
        await _ok(bus, _daemon("AddMatch", "s", [NOTIFICATIONS]))
        await bus.request_name(BLUEZ, NameFlag.DO_NOT_QUEUE)
        self.bus = bus

    async def stop(self) -> None:
        """bluetoothd exits: its connection and everything it knew are gone."""
        if self.bus is not None:
            self.bus.disconnect()
            self.bus = None
        self.app = self.advertisement = None

    async def restart(self) -> None:
        await self.stop()
        await asyncio.sleep(0.1)  # a real restart takes a moment
        await self.start()

    async def release_advertisement(self) -> None:
        """Drop the advertisement as bluetoothd does when the adapter is powered off."""
        assert self.bus is not None and self.advertisement is not None
        held, self.advertisement = self.advertisement, None
        await _ok(self.bus, Message(destination=held.sender, path=held.path,
                                    interface=ADVERTISEMENT, member="Release"))

    async def registered(self, timeout: float = WAIT) -> None:
        """Wait until both the application and the advertisement are registered."""
        await until(lambda: self.app is not None and self.advertisement is not None
                     and bool(self.app.objects), timeout)

    # the phone's side -------------------------------------------------------------

    def path_of(self, uuid: str) -> str:
        """The object path of the characteristic with `uuid`, as a phone finds it."""
        assert self.app is not None, "no application registered"
        for path, interfaces in self.app.objects.items():
            props = interfaces.get(CHARACTERISTIC)
            if props is not None and props["UUID"] == uuid:
                return path
        raise KeyError(uuid)

    def descriptor_of(self, char_uuid: str) -> str:
        assert self.app is not None
        char = self.path_of(char_uuid)
        return str(self.app.objects[char][CHARACTERISTIC]["Descriptors"][0])

    async def read(self, uuid: str, device: str, offset: int = 0) -> bytes:
        options = {"device": Variant("o", device)}
        if offset:
            options["offset"] = Variant("q", offset)
        reply = await self._app_call(self.path_of(uuid), CHARACTERISTIC, "ReadValue",
                                     "a{sv}", [options])
        return bytes(reply.body[0])

    async def read_descriptor(self, char_uuid: str) -> bytes:
        reply = await self._app_call(self.descriptor_of(char_uuid), DESCRIPTOR, "ReadValue",
                                     "a{sv}", [{}])
        return bytes(reply.body[0])

    async def write(self, uuid: str, value: bytes, device: str) -> None:
        options = {"device": Variant("o", device), "type": Variant("s", "request")}
        await self._app_call(self.path_of(uuid), CHARACTERISTIC, "WriteValue", "aya{sv}",
                             [value, options])

    async def start_notify(self, uuid: str) -> None:
        await self._app_call(self.path_of(uuid), CHARACTERISTIC, "StartNotify", "", [])

    async def stop_notify(self, uuid: str) -> None:
        await self._app_call(self.path_of(uuid), CHARACTERISTIC, "StopNotify", "", [])

    async def sync(self) -> None:
        """A round trip to the application: every signal it sent before is now here."""
        assert self.app is not None
        await self._app_call(self.app.path, "org.freedesktop.DBus.ObjectManager",
                             "GetManagedObjects", "", [])

    async def _app_call(self, path: str, interface: str, member: str, signature: str,
                        body: list[Any]) -> Message:
        assert self.bus is not None and self.app is not None
        msg = Message(destination=self.app.sender, path=path, interface=interface,
                      member=member, signature=signature, body=body)
        reply = await asyncio.wait_for(self.bus.call(msg), WAIT)
        assert reply is not None
        if reply.message_type is MessageType.ERROR:
            raise PhoneError(reply.error_name)
        return reply

    # bluetoothd's side --------------------------------------------------------------

    def _on_message(self, msg: Message) -> Message | bool | None:
        """Record and answer each call to bluetoothd; collect the notifications."""
        if msg.message_type is MessageType.SIGNAL:
            self._notified(msg)
            return None
        if msg.message_type is not MessageType.METHOD_CALL:
            return None
        self.events.append((str(msg.member), str(msg.body[0]) if msg.body else ""))
        if msg.path in self.devices:
            return self._device_call(msg)
        if msg.path != self.adapter:
            return Message.new_error(msg, "org.freedesktop.DBus.Error.UnknownObject",
                                     f"no object {msg.path}")
        task = asyncio.ensure_future(self._manage(msg))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return True  # answered by _manage once it has read the caller's objects

    async def _manage(self, msg: Message) -> None:
        assert self.bus is not None
        bus = self.bus
        call = (msg.interface, msg.member)
        if call == (GATT_MANAGER, "RegisterApplication"):
            await asyncio.sleep(self.pause)
            reply = await self._register_app(msg)
            await asyncio.sleep(self.pause)
        elif call == (ADVERTISING_MANAGER, "RegisterAdvertisement"):
            await asyncio.sleep(self.pause)
            reply = await self._register_advertisement(msg)
            await asyncio.sleep(self.pause)
        elif call == (GATT_MANAGER, "UnregisterApplication"):
            reply = self._unregister(msg, "app")
        elif call == (ADVERTISING_MANAGER, "UnregisterAdvertisement"):
            reply = self._unregister(msg, "advertisement")
            if reply.message_type is MessageType.METHOD_RETURN:
                bus.send(Message(destination=msg.sender, path=msg.body[0],
                                 interface=ADVERTISEMENT, member="Release",
                                 flags=MessageFlag.NO_REPLY_EXPECTED))
        else:
            reply = Message.new_error(msg, "org.freedesktop.DBus.Error.UnknownMethod",
                                      f"{msg.member} is not on {self.adapter}")
        if bus.connected:
            bus.send(reply)

    async def _register_app(self, msg: Message) -> Message:
        if self.app is not None:
            return Message.new_error(msg, "org.bluez.Error.AlreadyExists", "Already Exists")
        assert self.bus is not None
        ask = Message(destination=msg.sender, path=msg.body[0],
                      interface="org.freedesktop.DBus.ObjectManager",
                      member="GetManagedObjects")
        answer = await asyncio.wait_for(self.bus.call(ask), WAIT)
        if answer is None or answer.message_type is MessageType.ERROR:
            return Message.new_error(msg, "org.bluez.Error.Failed", "no objects")
        objects = plain(answer.body[0])
        fault = tree_fault(objects)
        if fault is not None:  # bluetoothd logs the reason and fails the registration
            return Message.new_error(msg, "org.bluez.Error.Failed", fault)
        self.app = Registration(str(msg.sender), msg.body[0], objects)
        return Message.new_method_return(msg)

    async def _register_advertisement(self, msg: Message) -> Message:
        if self.advertisement is not None:
            return Message.new_error(msg, "org.bluez.Error.AlreadyExists", "Already Exists")
        assert self.bus is not None
        ask = Message(destination=msg.sender, path=msg.body[0], interface=PROPERTIES,
                      member="GetAll", signature="s", body=[ADVERTISEMENT])
        answer = await asyncio.wait_for(self.bus.call(ask), WAIT)
        if answer is None or answer.message_type is MessageType.ERROR:
            return Message.new_error(msg, "org.bluez.Error.Failed", "Failed to parse")
        self.advertisement = Registration(str(msg.sender), msg.body[0],
                                          {msg.body[0]: {ADVERTISEMENT: plain(answer.body[0])}})
        return Message.new_method_return(msg)

    def _unregister(self, msg: Message, which: str) -> Message:
        held: Registration | None = getattr(self, which)
        if held is None or held.path != msg.body[0] or held.sender != msg.sender:
            return Message.new_error(msg, "org.bluez.Error.DoesNotExist", "Does Not Exist")
        setattr(self, which, None)
        return Message.new_method_return(msg)

    # the phones' device objects ----------------------------------------------------

    def _device_call(self, msg: Message) -> Message:
        """`org.bluez.Device1`'s properties of a phone bluetoothd knows (`devices`: its
        object path → e.g. {"Address": "AA:…", "Name": "Pixel 7", "Alias": "Pixel 7"}),
        read as BlueZ serves them: `Properties.GetAll` and `Get`. A phone that is not in
        `devices` is an unknown object, as for BlueZ one it never saw."""
        props = {k: Variant("s", v) for k, v in self.devices[str(msg.path)].items()}
        call = (msg.interface, msg.member)
        if call == (PROPERTIES, "GetAll") and msg.body == [DEVICE]:
            return Message.new_method_return(msg, "a{sv}", [props])
        if call == (PROPERTIES, "Get") and msg.body[:1] == [DEVICE] and msg.body[1] in props:
            return Message.new_method_return(msg, "v", [props[msg.body[1]]])
        return Message.new_error(msg, "org.freedesktop.DBus.Error.InvalidArgs",
                                 f"{msg.member} {msg.body} on {msg.path}")

    def _notified(self, msg: Message) -> None:
        if (self.app is None or msg.member != "PropertiesChanged"
                or msg.sender != self.app.sender or msg.body[0] != CHARACTERISTIC):
            return
        value = msg.body[1].get("Value")
        props = self.app.objects.get(str(msg.path), {}).get(CHARACTERISTIC)
        if value is not None and props is not None:
            self.notifications.setdefault(props["UUID"], []).append(bytes(value.value))


def tree_fault(objects: dict[str, dict[str, dict[str, Any]]]) -> str | None:
    """What bluetoothd's gatt-database would refuse in an application's objects: a
    characteristic of an unknown service, a descriptor of an unknown characteristic, a
    flag it does not know, a UUID it cannot parse; None when it would accept them."""
    def of(interface: str) -> dict[str, dict[str, Any]]:
        return {p: i[interface] for p, i in objects.items() if interface in i}

    services, chars = of(SERVICE), of(CHARACTERISTIC)
    if not services:
        return "no service"
    for path, props in services.items():
        if not _uuid(props.get("UUID")) or not isinstance(props.get("Primary"), bool):
            return f"{path}: bad service"
    for owner, kind, parent, flags in ((services, CHARACTERISTIC, "Service", CHAR_FLAGS),
                                       (chars, DESCRIPTOR, "Characteristic", DESC_FLAGS)):
        for path, props in of(kind).items():
            if props.get(parent) not in owner or not _uuid(props.get("UUID")):
                return f"{path}: no {parent} or bad UUID"
            if not props.get("Flags") or not set(props["Flags"]) <= flags:
                return f"{path}: bad flags {props.get('Flags')}"
    return None


def _uuid(value: Any) -> bool:
    text = str(value)
    return bool(re.fullmatch(r"[0-9a-fA-F]{4}|[0-9a-fA-F]{8}(-[0-9a-fA-F]{4}){3}-"
                             r"[0-9a-fA-F]{12}", text))


def _daemon(member: str, signature: str, body: list[Any]) -> Message:
    return Message(destination="org.freedesktop.DBus", path="/org/freedesktop/DBus",
                   interface="org.freedesktop.DBus", member=member, signature=signature,
                   body=body)


async def _ok(bus: MessageBus, msg: Message) -> None:
    reply = await asyncio.wait_for(bus.call(msg), WAIT)
    assert reply is not None and reply.message_type is MessageType.METHOD_RETURN, reply


async def until(condition: Callable[[], bool], timeout: float) -> None:
    """Poll `condition()` every 20 ms; TimeoutError after `timeout` seconds."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        if loop.time() > deadline:
            raise asyncio.TimeoutError(f"not true after {timeout} s")
        await asyncio.sleep(0.02)

