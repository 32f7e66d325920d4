"""The GATT tree and the advertisement Privzone expects, as data.

Privzone (the field's phone app, Web Bluetooth) asks for a device advertising SERVICE_UUID
(`requestDevice({filters: [{services: [...]}]})` in its MapPage.js; the chooser shows the
name `CIRCLES`), then looks characteristics up by UUID and lists (never reads) the
descriptors of two of them, so these values are a wire contract with phones in the field:
they are libpanda's `scripts/bluezone/bluezone.py` (`CirclesService`, its characteristics
and descriptors, `CirclesAdvertisement`) written down as values, in bluezone's order (the
order BlueZ lists them in, `char0` … `char6`). Nothing here touches the bus; tree.py
and server.py export it.

Two of bluezone's choices are kept on purpose although they look odd:

- The descriptors carry 16-bit UUIDs of standard descriptor types (`2904` is the
  Characteristic Presentation Format, …) whose value is a text label; the phone only lists
  them, so they are kept as they were rather than "fixed" into something untested.
- The advertisement's type is `broadcast`, not `peripheral` (bluezone has the latter
  commented out), and it asks for `IncludeTxPower`, a property BlueZ since 5.4x ignores
  (it reads `Includes: ["tx-power"]`). BlueZ makes a broadcast advertisement
  non-connectable, so phones in the field reach the car because its adapter is otherwise
  connectable (discoverable, as bluezone's install.sh sets it up); that is what works
  today, so it is kept, and ADVERTISEMENT_TYPE is the one value to change if a car's
  phones see CIRCLES but cannot connect.

One choice is lpam's own: the flags below are bluezone's, and they are what the tree
exports only with `lpam ble --writes open`. By default (`Writes.BONDED`) every `write`
becomes `encrypt-write` (`flags_for`): BlueZ then answers a write over a link that is not
encrypted with ATT's "Insufficient Encryption" without ever calling lpam, and a link is
encrypted only with a phone that has paired with the car (bonded: it keeps the keys).
Reads that only report stay open.
"""

from __future__ import annotations

from enum import Enum

from schemas.bluetooth import Writes

SERVICE_UUID = "00000001-4d3d-3d3d-3d3d-3d3d3d3d3d3d"
LOCAL_NAME = "CIRCLES"
ADVERTISEMENT_TYPE = "broadcast"
INCLUDE_TX_POWER = True

_CIRCLES = "-4d3d-3d3d-3d3d-3d3d3d3d3d3d"  # the Circles characteristics' UUID suffix
_THERMOMETER = "-710e-4a5b-8d75-3e5b444bc3cf"  # Otwell's cputemp example's suffix


class Characteristic(Enum):
    """One characteristic of the Circles service: UUID, flags and its one descriptor.

    Members are listed in bluezone's order; `uuid` is what the phone looks up.
    """

    TEMPERATURE = ("00000002" + _THERMOMETER, ("notify", "read"), "2906", "CPU Temperature")
    UNIT = ("00000003" + _THERMOMETER, ("read", "write"), "2903",
            "Temperature Units (F or C)")
    OUTPUT = ("00000002" + _CIRCLES, ("notify", "read"), "2910", "CIRCLES Output descriptor")
    INPUT = ("00000005" + _CIRCLES, ("write",), "2905", "Circles Input")
    COMMAND = ("00000003" + _CIRCLES, ("read", "write"), "2904", "Circles Command")
    CONFIG = ("00000004" + _CIRCLES, ("read", "write"), "2904", "Circles Config")
    STATUS = ("00000006" + _CIRCLES, ("notify", "read"), "2906", "Circles Status")

    def __init__(self, uuid: str, flags: tuple[str, ...], descriptor_uuid: str,
                 descriptor_text: str) -> None:
        self.uuid = uuid
        self.flags = flags
        self.descriptor_uuid = descriptor_uuid
        self.descriptor_text = descriptor_text

    @property
    def descriptor_value(self) -> bytes:
        """What a read of the descriptor answers: its label in ASCII, as bluezone did."""
        return self.descriptor_text.encode("ascii")

    @property
    def readable(self) -> bool:
        return "read" in self.flags

    @property
    def writable(self) -> bool:
        return "write" in self.flags

    @property
    def notifies(self) -> bool:
        return "notify" in self.flags


DESCRIPTOR_FLAGS = ("read",)

WRITE = "write"
ENCRYPTED_WRITE = "encrypt-write"


def flags_for(char: Characteristic, writes: Writes) -> tuple[str, ...]:
    """The flags `char` is exported with when `writes` says who may change the car.

    `encrypt-write`, not `encrypt-authenticated-write`: the Pi has no screen and no
    keyboard, so its agent's capability is NoInputNoOutput and every pairing is Just Works,
    which gives an encrypted link that is *not* authenticated (no passkey was compared).
    The authenticated variant would refuse every phone, paired or not. What keeps a
    stranger out is therefore when pairing is possible at all: only inside the window
    `lpam ble pair` opens (adapters/bluez/pairing.py)."""
    if writes is Writes.OPEN:
        return char.flags
    return tuple(ENCRYPTED_WRITE if flag == WRITE else flag for flag in char.flags)
