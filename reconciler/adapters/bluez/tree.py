"""The D-Bus objects lpam exports for BlueZ: their paths and their properties.

BlueZ learns a GATT application from one `GetManagedObjects` call on the application's
root (`org.freedesktop.DBus.ObjectManager`) and an advertisement from its
`org.freedesktop.DBus.Properties` (see BlueZ's doc/org.bluez.GattManager.rst and
org.bluez.LEAdvertisingManager.rst). The tree is fixed for the life of the process, so it
is computed once from `shape.py` for the write mode the service runs in (`Writes`: only
the characteristics' flags differ); `objects.py` answers the calls from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

from dbus_fast import Variant

from reconciler.adapters.bluez.shape import (
    ADVERTISEMENT_TYPE,
    DESCRIPTOR_FLAGS,
    INCLUDE_TX_POWER,
    LOCAL_NAME,
    SERVICE_UUID,
    Characteristic,
    flags_for,
)
from schemas.bluetooth import Writes

SERVICE_IFACE = "org.bluez.GattService1"
CHARACTERISTIC_IFACE = "org.bluez.GattCharacteristic1"
DESCRIPTOR_IFACE = "org.bluez.GattDescriptor1"
ADVERTISEMENT_IFACE = "org.bluez.LEAdvertisement1"
PROPERTIES_IFACE = "org.freedesktop.DBus.Properties"
OBJECT_MANAGER_IFACE = "org.freedesktop.DBus.ObjectManager"

# lpam's own prefix, so that bluezone (which used /org/bluez/example/…) and lpam never
# claim the same path should both run during a migration.
ROOT = "/org/lpam/privzone"
SERVICE = ROOT + "/service0"
ADVERTISEMENT = ROOT + "/advertisement0"

Properties = dict[str, Variant]


@dataclass(frozen=True)
class Node:
    """One exported object: its interface, its properties, and the characteristic it
    belongs to (None for the service and the advertisement)."""

    path: str
    interface: str
    properties: Properties
    characteristic: Characteristic | None = None


def characteristic_path(char: Characteristic) -> str:
    return f"{SERVICE}/char{list(Characteristic).index(char)}"


def descriptor_path(char: Characteristic) -> str:
    return characteristic_path(char) + "/desc0"


def _gatt_nodes(writes: Writes) -> list[Node]:
    chars = list(Characteristic)
    nodes = [Node(SERVICE, SERVICE_IFACE, {
        "UUID": Variant("s", SERVICE_UUID),
        "Primary": Variant("b", True),
        "Characteristics": Variant("ao", [characteristic_path(c) for c in chars]),
    })]
    for char in chars:
        nodes.append(Node(characteristic_path(char), CHARACTERISTIC_IFACE, {
            "Service": Variant("o", SERVICE),
            "UUID": Variant("s", char.uuid),
            "Flags": Variant("as", list(flags_for(char, writes))),
            "Descriptors": Variant("ao", [descriptor_path(char)]),
        }, char))
        nodes.append(Node(descriptor_path(char), DESCRIPTOR_IFACE, {
            "Characteristic": Variant("o", characteristic_path(char)),
            "UUID": Variant("s", char.descriptor_uuid),
            "Flags": Variant("as", list(DESCRIPTOR_FLAGS)),
        }, char))
    return nodes


def _advertisement_node() -> Node:
    return Node(ADVERTISEMENT, ADVERTISEMENT_IFACE, {
        "Type": Variant("s", ADVERTISEMENT_TYPE),
        "LocalName": Variant("s", LOCAL_NAME),
        "ServiceUUIDs": Variant("as", [SERVICE_UUID]),
        "IncludeTxPower": Variant("b", INCLUDE_TX_POWER),
    })


@dataclass(frozen=True)
class Tree:
    """Every exported object of one write mode: the GATT service's (`gatt`, in bluezone's
    order) and the advertisement, by path (`nodes`)."""

    gatt: tuple[Node, ...]
    nodes: dict[str, Node]

    def managed_objects(self) -> dict[str, dict[str, Properties]]:
        """The answer to `GetManagedObjects` on ROOT (signature `a{oa{sa{sv}}}`): the GATT
        service with its characteristics and descriptors, not the advertisement (BlueZ
        registers that separately and reads it through Properties)."""
        return {n.path: {n.interface: n.properties} for n in self.gatt}

    def properties_of(self, path: str, interface: str) -> Properties | None:
        """The properties of `interface` on `path`, or None when that object lacks it."""
        node = self.nodes.get(path)
        if node is None or node.interface != interface:
            return None
        return node.properties


@cache
def tree(writes: Writes) -> Tree:
    """The tree exported when `writes` says who may change the car."""
    gatt = tuple(_gatt_nodes(writes))
    return Tree(gatt, {n.path: n for n in (*gatt, _advertisement_node())})
