"""The GATT tree and the advertisement Privzone expects, as data.

Privzone (the field's phone app, Web Bluetooth) finds the car by the advertised local name
`CIRCLES` and then looks characteristics up by UUID, so these values are a wire contract
with phones already in the field: they are libpanda's `scripts/bluezone/bluezone.py`
(`CirclesService`, its characteristics and descriptors, `CirclesAdvertisement`) written
down as values, in bluezone's order (the order BlueZ lists them in, `char0` … `char6`).
Nothing here touches the bus; `server.py` exports it.

Two of bluezone's choices are kept on purpose although they look odd:

- The descriptors carry 16-bit UUIDs of standard descriptor types (`2904` is the
  Characteristic Presentation Format, …) whose value is a text label; the phone never
  reads them, so they are kept as they were rather than "fixed" into something untested.
- The advertisement's type is `broadcast`, not `peripheral` (bluezone has the latter
  commented out). A peripheral advertisement adds the 3-byte Flags field; with the 128-bit
  service UUID (18 bytes), the name (9) and the TX power (3) that would pass the 31 bytes
  of a legacy advertisement, which is the likely reason. Phones in the field connect to
  bluezone's advertisement, so it is copied as it is.
"""

from __future__ import annotations

from enum import Enum

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
