"""The exported objects' behaviour: BlueZ's method calls on lpam's GATT tree answered.

BlueZ turns a phone's ATT read, write or subscription into a D-Bus method call on the
characteristic's object (doc/org.bluez.GattCharacteristic.rst): `ReadValue(options)`,
`WriteValue(value, options)`, `StartNotify()`, `StopNotify()`, with the phone's device
object path in `options["device"]`. This module routes each to the `GattHandler` and turns
its answer (or its failure) into the reply; it never touches the socket, so `server.py`
owns the connection and this stays testable message by message.

The handler runs on the event loop's thread, inside the bus's receive path: while it runs,
no other message is read. `write` must therefore only hand the bytes over (to a queue, a
buffer) and return; a write that takes longer than SLOW_HANDLER is logged as a fault.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from typing import Any, Protocol

from dbus_fast import Message, MessageType, Variant

from reconciler.adapters.bluez.shape import Characteristic
from reconciler.adapters.bluez.tree import (
    ADVERTISEMENT,
    ADVERTISEMENT_IFACE,
    CHARACTERISTIC_IFACE,
    DESCRIPTOR_IFACE,
    OBJECT_MANAGER_IFACE,
    PROPERTIES_IFACE,
    ROOT,
    Tree,
    characteristic_path,
    tree,
)
from schemas.bluetooth import Writes

SLOW_HANDLER = 0.1  # seconds a handler may hold the loop before it is reported

ACCESS_DENIED = "org.freedesktop.DBus.Error.AccessDenied"
INVALID_ARGS = "org.freedesktop.DBus.Error.InvalidArgs"
UNKNOWN_METHOD = "org.freedesktop.DBus.Error.UnknownMethod"
FAILED = "org.bluez.Error.Failed"
NOT_PERMITTED = "org.bluez.Error.NotPermitted"


class GattHandler(Protocol):
    """What lpam does with the phone's requests (the Privzone protocol lives behind it)."""

    def read(self, char: Characteristic, device: str | None) -> bytes:
        """The characteristic's value for the phone `device` (a BlueZ device path)."""

    def write(self, char: Characteristic, value: bytes, device: str | None) -> None:
        """Take `value` written by the phone `device`. Must return at once: queue the
        work. A long write arrives as several calls in order (bluezone appended them)."""

    def subscribed(self, char: Characteristic, on: bool) -> None:
        """A phone started (`on`) or the last one stopped listening to `char`."""


class Objects:
    """Answers method calls on the exported tree (of the write mode `writes`); knows which
    characteristics notify."""

    def __init__(self, handler: GattHandler, *, log: Callable[[str], None],
                 released: Callable[[], None],
                 bug: Callable[[], str] = lambda: "(no debug log)",
                 writes: Writes = Writes.BONDED) -> None:
        self._handler = handler
        self._tree: Tree = tree(writes)
        self._log = log
        self._bug = bug
        self._released = released
        self.notifying: set[Characteristic] = set()

    def answer(self, msg: Message, bluez: str | None) -> Message | None:
        """The reply to `msg` if it is a call on one of lpam's objects, else None (the
        message is someone else's: a reply to lpam's own calls, a signal).

        Only bluetoothd (`bluez`, the unique name owning org.bluez) is answered: a write
        here can make lpam change the car's apps, so no other process on the system bus
        may pose as a phone, whatever the bus's policy allows."""
        if msg.message_type is not MessageType.METHOD_CALL:
            return None
        if msg.path != ROOT and msg.path not in self._tree.nodes:
            return None
        if bluez is None or msg.sender != bluez:
            return Message.new_error(msg, ACCESS_DENIED, "only bluetoothd is served")
        try:
            return self._dispatch(msg)
        except _Refused as refused:
            return Message.new_error(msg, refused.name, refused.text)
        except Exception as exc:  # a malformed call must cost one reply, not the service
            self._log(f"could not answer {msg.member} on {msg.path}: {exc!r} "
                      f"(details in {self._bug()})")
            return Message.new_error(msg, FAILED, "internal error")

    def forget(self) -> None:
        """bluetoothd is gone: its subscriptions went with it (it sends no StopNotify)."""
        gone, self.notifying = self.notifying, set()
        for char in sorted(gone, key=list(Characteristic).index):
            with contextlib.suppress(_Refused):  # logged by _call
                self._call(char, "subscription", self._handler.subscribed, char, False)

    def notification(self, char: Characteristic, value: bytes) -> Message | None:
        """The PropertiesChanged signal carrying `value`, or None when no phone listens."""
        if char not in self.notifying:
            return None
        return Message.new_signal(
            characteristic_path(char), PROPERTIES_IFACE, "PropertiesChanged", "sa{sv}as",
            [CHARACTERISTIC_IFACE, {"Value": Variant("ay", bytes(value))}, []])

    def _dispatch(self, msg: Message) -> Message:
        member = (msg.interface, msg.member, msg.signature)
        if member == (OBJECT_MANAGER_IFACE, "GetManagedObjects", "") and msg.path == ROOT:
            return Message.new_method_return(msg, "a{oa{sa{sv}}}", [self._tree.managed_objects()])
        if member == (PROPERTIES_IFACE, "GetAll", "s"):
            return Message.new_method_return(msg, "a{sv}", [self._properties(msg)])
        if member == (PROPERTIES_IFACE, "Get", "ss"):
            value = self._properties(msg).get(msg.body[1])
            if value is None:
                raise _Refused(INVALID_ARGS, f"no property {msg.body[1]}")
            return Message.new_method_return(msg, "v", [value])
        if member == (ADVERTISEMENT_IFACE, "Release", "") and msg.path == ADVERTISEMENT:
            self._log("bluetoothd released the advertisement")
            self._released()
            return Message.new_method_return(msg)
        node = self._tree.nodes.get(msg.path or "")
        if node is not None and node.characteristic is not None \
                and node.interface == msg.interface:
            return self._gatt(msg, node.characteristic)
        raise _Refused(UNKNOWN_METHOD, f"{msg.interface}.{msg.member}({msg.signature}) "
                                       f"is not on {msg.path}")

    def _properties(self, msg: Message) -> dict[str, Variant]:
        props = self._tree.properties_of(msg.path or "", msg.body[0])
        if props is None:
            raise _Refused(INVALID_ARGS, f"{msg.path} has no interface {msg.body[0]}")
        return props

    def _gatt(self, msg: Message, char: Characteristic) -> Message:
        call = (msg.interface, msg.member, msg.signature)
        if call == (DESCRIPTOR_IFACE, "ReadValue", "a{sv}"):
            return _value_reply(msg, char.descriptor_value, msg.body[0])
        if call == (CHARACTERISTIC_IFACE, "ReadValue", "a{sv}") and char.readable:
            options = msg.body[0]
            value = self._call(char, "read", self._handler.read, char, _device(options))
            return _value_reply(msg, value, options)
        if call == (CHARACTERISTIC_IFACE, "WriteValue", "aya{sv}") and char.writable:
            value, options = bytes(msg.body[0]), msg.body[1]
            self._call(char, "write", self._handler.write, char, value, _device(options))
            return Message.new_method_return(msg)
        if call[:2] == (CHARACTERISTIC_IFACE, "StartNotify") and char.notifies:
            return self._subscribe(msg, char, True)
        if call[:2] == (CHARACTERISTIC_IFACE, "StopNotify") and char.notifies:
            return self._subscribe(msg, char, False)
        if msg.member in ("ReadValue", "WriteValue", "StartNotify", "StopNotify"):
            raise _Refused(NOT_PERMITTED, f"{char.name.lower()} does not allow {msg.member}")
        raise _Refused(UNKNOWN_METHOD, f"{msg.member}({msg.signature}) is not on {msg.path}")

    def _subscribe(self, msg: Message, char: Characteristic, on: bool) -> Message:
        if on != (char in self.notifying):
            if on:
                self.notifying.add(char)
            else:
                self.notifying.discard(char)
            self._call(char, "subscription", self._handler.subscribed, char, on)
        return Message.new_method_return(msg)

    def _call(self, char: Characteristic, what: str, fn: Callable[..., Any],
              *args: Any) -> Any:
        """`fn(*args)`, its failure turned into org.bluez.Error.Failed and one log line
        (the phone sees a failed ATT request, the journal says why; never a traceback)."""
        started = time.monotonic()
        try:
            return fn(*args)
        except Exception as exc:  # the handler's fault must not end the service
            self._log(f"the {char.name.lower()} {what} failed: {type(exc).__name__}: {exc} "
                      f"(details in {self._bug()})")
            raise _Refused(FAILED, f"{what} failed") from None
        finally:
            spent = time.monotonic() - started
            if spent > SLOW_HANDLER:
                self._log(f"the {char.name.lower()} {what} held the bus for {spent:.2f} s "
                          "(a handler must hand work over, not do it)")


class _Refused(Exception):
    """A D-Bus error reply: its name and text."""

    def __init__(self, name: str, text: str) -> None:
        super().__init__(text)
        self.name = name
        self.text = text


def _device(options: dict[str, Variant]) -> str | None:
    device = options.get("device")
    return str(device.value) if device is not None else None


def _value_reply(msg: Message, value: bytes, options: dict[str, Variant]) -> Message:
    """`value` from the requested offset on: BlueZ reads a long value in pieces
    (`options["offset"]`), each asking for the rest of it."""
    offset = options.get("offset")
    start = int(offset.value) if offset is not None else 0
    if start > len(value):
        raise _Refused("org.bluez.Error.InvalidOffset", f"offset {start} > {len(value)}")
    return Message.new_method_return(msg, "ay", [bytes(value[start:])])
