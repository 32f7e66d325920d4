"""Who may pair with the car, on BlueZ: the pairing window, its agent, the bonded phones.

By default a write that changes the car needs a bonded phone (shape.py `flags_for`), so
what keeps a stranger out is when pairing is possible at all. This module opens that door
for a bounded time and closes it (doc/org.bluez.Adapter.rst, org.bluez.AgentManager.rst,
org.bluez.Agent.rst, org.bluez.Device.rst):

- `window` makes the adapter pairable and discoverable (`Pairable`, `PairableTimeout`,
  `Discoverable`, `DiscoverableTimeout`, set through org.freedesktop.DBus.Properties),
  registers an agent (`AgentManager1.RegisterAgent` with capability NoInputNoOutput, then
  `RequestDefaultAgent`, so that it answers the pairings of phones, not only of
  lpam's own calls) and, when the time is up or it is stopped, makes the adapter not
  pairable, puts `Discoverable` and both timeouts back as they were, and unregisters the
  agent. `Discoverable` is put back rather than switched off because the advertisement is
  a non-connectable `broadcast` (shape.py): a car whose phones reach it through a
  discoverable adapter (bluezone's setup) must stay reachable by its bonded phones. The
  timeouts are BlueZ's own safety net should lpam die with the window open.
- The agent accepts each pairing inside the window: the Pi has no screen and no keys
  (NoInputNoOutput, so Just Works), there is no one to ask, and the window was opened by
  a person at the car with root's rights, for the phone in their hand. It accepts
  `RequestConfirmation`, `RequestAuthorization` and `AuthorizeService`, and refuses what
  it cannot do (a PIN or passkey to type: `org.bluez.Error.Rejected`).
- `phones` lists the devices under the adapter that are paired or bonded (one
  `GetManagedObjects` of org.bluez); `forget` removes one (`Adapter1.RemoveDevice`), which
  deletes its keys: its writes are refused from then on.

Only bluetoothd (the owner of org.bluez) is answered on the agent's path, as on the GATT
objects (objects.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from dbus_fast import BusType, Message, MessageType, Variant
from dbus_fast.aio import MessageBus

from reconciler.adapters.bluez.server import ADAPTER_IFACE, BLUEZ, DBUS, explain
from reconciler.adapters.bluez.tree import OBJECT_MANAGER_IFACE, PROPERTIES_IFACE
from reconciler.base.errors import LpamError

ADAPTER = ADAPTER_IFACE
AGENT_MANAGER = "org.bluez.AgentManager1"
AGENT = "org.bluez.Agent1"
DEVICE = "org.bluez.Device1"
PROPERTIES = PROPERTIES_IFACE
OBJECT_MANAGER = OBJECT_MANAGER_IFACE
MANAGER_PATH = "/org/bluez"
AGENT_PATH = "/org/lpam/agent"
CAPABILITY = "NoInputNoOutput"
"""The Pi has no display and no keyboard: every pairing is Just Works."""
CALL_TIMEOUT = 10.0
REJECTED = "org.bluez.Error.Rejected"
WINDOW = ("Pairable", "PairableTimeout", "Discoverable", "DiscoverableTimeout")
_ADDRESS = re.compile(r"[0-9A-Fa-f]{2}(:[0-9A-Fa-f]{2}){5}")


@dataclass(frozen=True)
class Phone:
    """A device bluetoothd knows under the adapter, with what it says of the bond."""

    address: str
    name: str | None
    paired: bool
    bonded: bool
    path: str


def check_address(text: str) -> str:
    """`AA:BB:CC:DD:EE:FF`, upper case; an LpamError for anything else."""
    if not _ADDRESS.fullmatch(text):
        raise LpamError(f"{text!r} is not a Bluetooth address",
                        hint="write it as six pairs of hex digits: AA:BB:CC:DD:EE:FF "
                        "(`lpam ble phones` lists the bonded phones)")
    return text.upper()


async def window(*, bus_address: str | None, adapter: str, seconds: int,
                 stopped: Callable[[], bool], opened: Callable[[], None],
                 paired: Callable[[str], None]) -> None:
    """Let phones pair for `seconds` (or until `stopped()`), then close the window.
    `opened` is called once the window is open; `paired` hears each accepted pairing:
    the phone's address (and its name in brackets, if bluetoothd knows it)."""
    bus = await _connect(bus_address)
    agent = _Agent(bus, paired)
    bus.add_message_handler(agent.answer)
    try:
        agent.bluez = str(await _call(bus, adapter, Message(
            destination=DBUS, path="/org/freedesktop/DBus", interface=DBUS,
            member="GetNameOwner", signature="s", body=[BLUEZ])))
        before = {name: await _get(bus, adapter, name) for name in WINDOW}
        await _manage(bus, adapter, "RegisterAgent", "os", [AGENT_PATH, CAPABILITY])
        try:
            await _manage(bus, adapter, "RequestDefaultAgent", "o", [AGENT_PATH])
            try:
                await _set(bus, adapter, "PairableTimeout", Variant("u", seconds))
                await _set(bus, adapter, "DiscoverableTimeout", Variant("u", seconds))
                await _set(bus, adapter, "Pairable", Variant("b", True))
                await _set(bus, adapter, "Discoverable", Variant("b", True))
                opened()
                await _wait(seconds, stopped)
            finally:
                await _close(bus, adapter, before)
        finally:
            with contextlib.suppress(LpamError):  # bluetoothd drops it as lpam leaves
                await _manage(bus, adapter, "UnregisterAgent", "o", [AGENT_PATH])
    finally:
        bus.disconnect()


async def phones(*, bus_address: str | None, adapter: str) -> list[Phone]:
    """The paired or bonded devices under `adapter`, by address."""
    bus = await _connect(bus_address)
    try:
        return sorted((p for p in await _devices(bus, adapter) if p.paired or p.bonded),
                      key=lambda p: p.address)
    finally:
        bus.disconnect()


async def forget(*, bus_address: str | None, adapter: str, address: str) -> Phone:
    """Remove the bonded phone `address` (its keys with it); the phone that was removed.
    A device bluetoothd only saw in a scan is not a phone of the car's: refused by name."""
    wanted = check_address(address)
    bus = await _connect(bus_address)
    try:
        found = [p for p in await _devices(bus, adapter)
                 if p.address.upper() == wanted and (p.paired or p.bonded)]
        if not found:
            raise LpamError(f"no phone {wanted} is bonded with {adapter}",
                            hint="`lpam ble phones` lists the bonded phones")
        await _call(bus, adapter, Message(destination=BLUEZ, path=adapter, interface=ADAPTER,
                                          member="RemoveDevice", signature="o",
                                          body=[found[0].path]))
        return found[0]
    finally:
        bus.disconnect()


class _Agent:
    """org.bluez.Agent1 on AGENT_PATH: accepts what a Just Works pairing asks."""

    ACCEPT = frozenset({"RequestConfirmation", "RequestAuthorization", "AuthorizeService"})
    QUIET = frozenset({"Release", "Cancel", "DisplayPasskey", "DisplayPinCode"})

    def __init__(self, bus: MessageBus, said: Callable[[str], None]) -> None:
        self._bus = bus
        self._said = said
        self.bluez: str | None = None

    def answer(self, msg: Message) -> Message | None:
        if msg.message_type is not MessageType.METHOD_CALL or msg.path != AGENT_PATH:
            return None
        if self.bluez is None or msg.sender != self.bluez:
            return Message.new_error(msg, "org.freedesktop.DBus.Error.AccessDenied",
                                     "only bluetoothd is answered")
        if msg.interface != AGENT:
            return Message.new_error(msg, "org.freedesktop.DBus.Error.UnknownMethod",
                                     f"{msg.interface}.{msg.member} is not on {AGENT_PATH}")
        if msg.member in self.ACCEPT:
            if msg.member != "AuthorizeService":  # a service of a phone already paired
                task = asyncio.ensure_future(self._tell(str(msg.body[0])))
                task.add_done_callback(lambda t: t.cancelled() or t.exception())
            return Message.new_method_return(msg)
        if msg.member in self.QUIET:
            return Message.new_method_return(msg)
        return Message.new_error(msg, REJECTED, "the car has no keyboard: Just Works only")

    async def _tell(self, device: str) -> None:
        address = device.rsplit("/dev_", 1)[-1].replace("_", ":")
        with contextlib.suppress(LpamError):
            name = await _get(self._bus, device, "Name", interface=DEVICE)
            address = f"{address} ({name.value})"
        self._said(address)


async def _connect(address: str | None) -> MessageBus:
    where = address or "the system bus"
    try:
        return await asyncio.wait_for(
            MessageBus(bus_address=address, bus_type=BusType.SYSTEM).connect(), CALL_TIMEOUT)
    except Exception as exc:  # no socket, refused, auth, no answer: one line each
        raise LpamError(f"cannot connect to {where}: {exc or type(exc).__name__}",
                        hint="is dbus running? (`--bus ADDRESS` names another bus)") from None


async def _call(bus: MessageBus, adapter: str, msg: Message) -> Any:
    """The first value of the reply to `msg` (None if it has none); an LpamError for an
    error reply, in the words of server.py's `explain`."""
    try:
        reply = await asyncio.wait_for(bus.call(msg), CALL_TIMEOUT)
    except asyncio.TimeoutError:
        raise LpamError(f"bluetoothd did not answer {msg.member} in {CALL_TIMEOUT:g} s",
                        hint="is bluetoothd hung? (`systemctl status bluetooth`)") from None
    assert reply is not None
    if reply.message_type is MessageType.ERROR:
        text = reply.body[0] if reply.body else ""
        raise LpamError(f"{msg.member} on {adapter}: "
                        f"{explain(f'{reply.error_name}: {text}', adapter)}")
    return reply.body[0] if reply.body else None


async def _manage(bus: MessageBus, adapter: str, member: str, signature: str,
                  body: list[Any]) -> None:
    await _call(bus, adapter, Message(destination=BLUEZ, path=MANAGER_PATH,
                                      interface=AGENT_MANAGER, member=member,
                                      signature=signature, body=body))


async def _get(bus: MessageBus, path: str, name: str, *, interface: str = ADAPTER) -> Variant:
    value = await _call(bus, path, Message(destination=BLUEZ, path=path, interface=PROPERTIES,
                                           member="Get", signature="ss",
                                           body=[interface, name]))
    assert isinstance(value, Variant)
    return value


async def _set(bus: MessageBus, adapter: str, name: str, value: Variant) -> None:
    await _call(bus, adapter, Message(destination=BLUEZ, path=adapter, interface=PROPERTIES,
                                      member="Set", signature="ssv",
                                      body=[ADAPTER, name, value]))


async def _wait(seconds: int, stopped: Callable[[], bool]) -> None:
    """`seconds`, cut short by `stopped()` (a signal seen by the caller's handler)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + seconds
    while not stopped() and loop.time() < deadline:
        await asyncio.sleep(min(0.1, max(deadline - loop.time(), 0)))


async def _close(bus: MessageBus, adapter: str, before: dict[str, Variant]) -> None:
    """Not pairable any more; discoverable, and both timeouts, as they were."""
    await _set(bus, adapter, "Pairable", Variant("b", False))
    for name in ("Discoverable", "DiscoverableTimeout", "PairableTimeout"):
        await _set(bus, adapter, name, before[name])


async def _devices(bus: MessageBus, adapter: str) -> list[Phone]:
    objects = await _call(bus, adapter, Message(destination=BLUEZ, path="/",
                                                interface=OBJECT_MANAGER,
                                                member="GetManagedObjects"))
    found = []
    for path, interfaces in dict(objects).items():
        props = interfaces.get(DEVICE)
        if props is None or not str(path).startswith(adapter + "/"):
            continue
        value = {k: v.value for k, v in props.items()}
        found.append(Phone(address=str(value.get("Address", "")),
                           name=None if value.get("Name") is None else str(value["Name"]),
                           paired=bool(value.get("Paired")), bonded=bool(value.get("Bonded")),
                           path=str(path)))
    return found
