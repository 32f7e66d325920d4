"""The phone behind a write, as BlueZ knows it: its address and, when it has one, its name.

BlueZ hands lpam the phone's device object path with every read and write
(`options["device"]`, e.g. `/org/bluez/hci0/dev_AA_BB_CC_DD_EE_FF`); the device object
(`org.bluez.Device1`, doc/org.bluez.Device.rst) has its `Address`, the `Name` the phone
advertised (if any) and the `Alias` a user may have set. lpam records who asked for a
change (reconciler/workflow/actor.py), so the Bluetooth service asks BlueZ for these
(server.py `GattServer.device`). The address is also in the path itself: what
`address_in` reads, pure, where nothing may wait on the bus (the GATT loop logging a
refusal) or where BlueZ does not answer.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

DEVICE_IFACE = "org.bluez.Device1"

_PATH = re.compile(r"/dev_((?:[0-9A-Fa-f]{2}_){5}[0-9A-Fa-f]{2})$")


@dataclass(frozen=True)
class Device:
    """A phone: its Bluetooth address (None: not known) and its name (None: none)."""

    address: str | None
    name: str | None = None

    @property
    def shown(self) -> str:
        """For the service's log: the address, and the name when there is one."""
        address = self.address or "an unknown phone"
        return f"{address} ({self.name})" if self.name else address


def address_in(path: str | None) -> str | None:
    """The address a BlueZ device path spells (`dev_AA_BB_…` → `AA:BB:…`), else None."""
    found = _PATH.search(path or "")
    return found.group(1).replace("_", ":").upper() if found else None


def device_of(path: str | None, props: dict[str, Any] | None) -> Device:
    """The phone at `path` from its Device1 properties (plain values; None: BlueZ did not
    answer). BlueZ's `Alias` falls back to the address when the phone has no name and no
    user gave one: that is no name."""
    props = props or {}
    address = props.get("Address")
    address = str(address).upper() if isinstance(address, str) and address else \
        address_in(path)
    name = None
    for key in ("Alias", "Name"):
        value = props.get(key)
        if isinstance(value, str) and value.strip() and \
                value.replace("-", ":").upper() != (address or ""):
            name = value.strip()
            break
    return Device(address, name)
