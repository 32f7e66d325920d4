"""Privzone's Bluetooth LE transport: lpam's GATT service and advertisement on BlueZ.

`GattServer` (server.py) exports the tree of `shape.py` (tree.py) on the system D-Bus,
routes the phone's reads, writes and subscriptions to a `GattHandler` (objects.py) and
sends notifications; what the bytes mean is the Privzone protocol's business, not this
package's.
"""

from reconciler.adapters.bluez.objects import GattHandler
from reconciler.adapters.bluez.server import GattServer
from reconciler.adapters.bluez.shape import Characteristic

__all__ = ["Characteristic", "GattHandler", "GattServer"]
