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

Phones and bonding (the block "Devices" below): bluetoothd knows each phone as a device
object under the adapter. A write to a characteristic whose flags ask for encryption
(`encrypt-write`, …) from a phone whose link is not encrypted — one that has not paired
— never reaches the application: bluetoothd's ATT server answers "Insufficient
Encryption" (src/shared/gatt-server.c `check_permissions`), which BlueZ's own GATT client
relays as `org.bluez.Error.NotPermitted` "Not paired" (src/gatt-client.c
`create_gatt_dbus_error`); the double raises that as the phone's PhoneError and records
the refusal. Just Works pairing (the Pi has no screen) never authenticates the link, so
the `encrypt-authenticated-*` and `secure-*` flags refuse even a bonded phone.
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


NOT_PAIRED = "org.bluez.Error.NotPermitted"
"""What a BlueZ client hears for ATT's Insufficient Encryption/Authentication: "Not paired"."""
ENCRYPTED_WRITES = {"encrypt-write", "encrypt-authenticated-write", "secure-write"}
AUTHENTICATED_WRITES = {"encrypt-authenticated-write", "secure-write"}


@dataclass
class Registration:
    """What the double learnt from a registration: who, where, and what it read back."""

    sender: str
    path: str
    objects: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    raw: Any = None  # the objects as they came, Variants and all (marshalled again: bytes)


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
        self.devices: dict[str, Device] = {}  # path -> the phone bluetoothd knows
        self.refused: list[tuple[str, str]] = []  # (uuid, device) of writes it refused
        self.adapter_props: dict[str, Any] = dict(ADAPTER_DEFAULTS)
        self.adapter_sets: list[tuple[float, str, Any]] = []  # (loop time, name, value)
        self.agent: tuple[str, str, str] | None = None  # (sender, path, capability)
        self.release_at_once = 0  # advertisements to drop right after answering them
        self._tasks: set[asyncio.Future[Any]] = set()

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
        """The phone `device` writes `value`; refused here, as bluetoothd's ATT server
        refuses it, when the characteristic asks for a link this phone does not have."""
        assert self.app is not None
        flags = set(self.app.objects[self.path_of(uuid)][CHARACTERISTIC]["Flags"])
        known = self.devices.get(device)
        encrypted = known is not None and known.paired
        if (flags & ENCRYPTED_WRITES and not encrypted) or flags & AUTHENTICATED_WRITES:
            self.refused.append((uuid, device))
            raise PhoneError(NOT_PAIRED)
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
        answered = pairing_call(self, msg)
        if answered is not None:
            return answered
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
        if (call == (ADVERTISING_MANAGER, "RegisterAdvertisement") and self.release_at_once
                and self.advertisement is not None and bus.connected):
            # The adapter powered off as bluetoothd answered. lpam handles a Release as it
            # reads it, an answer a step later (its waiting task wakes): so a Release sent
            # right behind the answer is often seen first. Sent first, it always is.
            self.release_at_once -= 1
            held, self.advertisement = self.advertisement, None
            bus.send(Message(destination=held.sender, path=held.path, interface=ADVERTISEMENT,
                             member="Release", flags=MessageFlag.NO_REPLY_EXPECTED))
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
        self.app = Registration(str(msg.sender), msg.body[0], objects, answer.body[0])
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

    def _notified(self, msg: Message) -> None:
        if (self.app is None or msg.member != "PropertiesChanged"
                or msg.sender != self.app.sender or msg.body[0] != CHARACTERISTIC):
            return
        value = msg.body[1].get("Value")
        props = self.app.objects.get(str(msg.path), {}).get(CHARACTERISTIC)
        if value is not None and props is not None:
            self.notifications.setdefault(props["UUID"], []).append(bytes(value.value))


# Devices ------------------------------------------------------------------------------
# The phones bluetoothd knows, as device objects under the adapter (doc/org.bluez.Device.rst).


@dataclass
class Device:
    """A phone as bluetoothd's Device1 shows it. Paired: the link is encrypted with keys
    from a pairing; Bonded: the keys are stored (a phone pairing with the car bonds)."""

    address: str
    name: str | None = None
    paired: bool = False
    bonded: bool = False


def device_path(adapter: str, address: str) -> str:
    """`/org/bluez/hci0/dev_AA_BB_…`, as bluetoothd names a device object."""
    return f"{adapter}/dev_{address.upper().replace(':', '_')}"


def address_of(path: str) -> str:
    """The Bluetooth address of a device path (`dev_AA_BB_…` → `AA:BB:…`)."""
    return path.rsplit("/dev_", 1)[-1].replace("_", ":")


def bond(double: BluezDouble, path: str, name: str | None = None) -> Device:
    """Make the phone at `path` one that has paired and bonded with the car before."""
    device = double.devices.setdefault(path, Device(address_of(path), name))
    device.paired = device.bonded = True
    device.name = name if name is not None else device.name
    return device


# The adapter's pairing side: its properties, the agent manager, the device objects and
# RemoveDevice (doc/org.bluez.Adapter.rst, AgentManager.rst, Device.rst). The double keeps
# what it is told: it runs none of bluetoothd's own timers (PairableTimeout…), so a test
# sees whether lpam itself closes the pairing window.

ADAPTER = "org.bluez.Adapter1"
AGENT_MANAGER = "org.bluez.AgentManager1"
AGENT = "org.bluez.Agent1"
DEVICE = "org.bluez.Device1"
ADAPTER_DEFAULTS: dict[str, Any] = {
    "Address": "B8:27:EB:00:00:01", "Name": "raspberrypi", "Powered": True,
    "Pairable": True, "PairableTimeout": 0, "Discoverable": False,
    "DiscoverableTimeout": 180}  # BlueZ's defaults (Pairable true, 180 s discoverable)
_SIGNATURES = {bool: "b", int: "u", str: "s"}
NOT_PAIRABLE = "SMP Pairing Not Supported"
"""What a phone's pairing meets when the adapter is not pairable (the kernel's answer to
a pairing that asks to bond while the adapter is not bondable)."""


def pairing_call(double: BluezDouble, msg: Message) -> Message | None:
    """The reply to a call on the adapter's properties, the agent manager, a device or
    the object manager; None for every other call (the GATT managers')."""
    call, path = (msg.interface, msg.member), str(msg.path)
    adapter = path == double.adapter
    if call == (PROPERTIES, "Set") and adapter and msg.body[0] == ADAPTER:
        name, value = str(msg.body[1]), msg.body[2].value
        if name not in double.adapter_props or name in ("Address", "Name"):
            return Message.new_error(msg, "org.bluez.Error.InvalidArguments", name)
        double.adapter_props[name] = value
        double.adapter_sets.append((asyncio.get_running_loop().time(), name, value))
        return Message.new_method_return(msg)
    if call[0] == PROPERTIES and call[1] in ("Get", "GetAll"):
        props = (_variants(double.adapter_props) if adapter and msg.body[0] == ADAPTER
                 else _device_props(double, path) if msg.body[0] == DEVICE else None)
        if props is None or (call[1] == "Get" and msg.body[1] not in props):
            return Message.new_error(msg, "org.bluez.Error.InvalidArguments", path)
        if call[1] == "GetAll":
            return Message.new_method_return(msg, "a{sv}", [props])
        return Message.new_method_return(msg, "v", [props[msg.body[1]]])
    if call == ("org.freedesktop.DBus.ObjectManager", "GetManagedObjects") and path == "/":
        objects = {double.adapter: {ADAPTER: _variants(double.adapter_props)}}
        for device in double.devices:
            objects[device] = {DEVICE: _device_props(double, device) or {}}
        return Message.new_method_return(msg, "a{oa{sa{sv}}}", [objects])
    if call == (ADAPTER, "RemoveDevice") and adapter:
        if double.devices.pop(str(msg.body[0]), None) is None:
            return Message.new_error(msg, "org.bluez.Error.DoesNotExist", "Does Not Exist")
        return Message.new_method_return(msg)
    if call[0] == AGENT_MANAGER and path == "/org/bluez":
        return _agent_manager(double, msg)
    return None


def _agent_manager(double: BluezDouble, msg: Message) -> Message:
    held = double.agent
    if msg.member == "RegisterAgent":
        if held is not None and held[:2] == (msg.sender, msg.body[0]):
            return Message.new_error(msg, "org.bluez.Error.AlreadyExists", "Already Exists")
        double.agent = (str(msg.sender), str(msg.body[0]), str(msg.body[1]))
    elif msg.member in ("RequestDefaultAgent", "UnregisterAgent"):
        if held is None or held[:2] != (msg.sender, msg.body[0]):
            return Message.new_error(msg, "org.bluez.Error.DoesNotExist", "Does Not Exist")
        if msg.member == "UnregisterAgent":
            double.agent = None
    else:
        return Message.new_error(msg, "org.freedesktop.DBus.Error.UnknownMethod",
                                 str(msg.member))
    return Message.new_method_return(msg)


def _variants(props: dict[str, Any]) -> dict[str, Variant]:
    return {k: Variant(_SIGNATURES[type(v)], v) for k, v in props.items()}


def _device_props(double: BluezDouble, path: str) -> dict[str, Variant] | None:
    device = double.devices.get(path)
    if device is None:
        return None
    props = {"Address": Variant("s", device.address), "Adapter": Variant("o", double.adapter),
             "Paired": Variant("b", device.paired), "Bonded": Variant("b", device.bonded)}
    if device.name is not None:
        props["Name"] = Variant("s", device.name)
    # BlueZ's Alias: the name, else the address with dashes (doc/org.bluez.Device.rst)
    props["Alias"] = Variant("s", device.name or device.address.replace(":", "-"))
    return props


async def pair_phone(double: BluezDouble, address: str, name: str | None = None, *,
                     method: str = "RequestConfirmation") -> Device:
    """A phone asks to pair, as bluetoothd relays it to the default agent (`method`:
    RequestConfirmation or RequestAuthorization, as the phone's capabilities make it);
    bonded when the agent accepts. PhoneError when the adapter is not pairable or the
    agent refuses."""
    assert double.bus is not None
    if not double.adapter_props["Pairable"]:
        raise PhoneError(NOT_PAIRABLE)
    if double.agent is None:
        raise PhoneError("org.bluez.Error.AuthenticationFailed")
    path = device_path(double.adapter, address)
    device = double.devices.setdefault(path, Device(address.upper(), name))
    sender, agent, _ = double.agent
    signature, body = ("ou", [path, 123456]) if method == "RequestConfirmation" else \
        ("o", [path])
    reply = await asyncio.wait_for(double.bus.call(Message(
        destination=sender, path=agent, interface=AGENT, member=method,
        signature=signature, body=body)), WAIT)
    assert reply is not None
    if reply.message_type is MessageType.ERROR:
        raise PhoneError(reply.error_name)
    device.paired = device.bonded = True
    return device


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

