"""One signal read out of one CAN frame: the pure core of the "is the car parked?" gate.

Before a cutover lpam asks the vehicle's speed (a car that moves must never have its control
app swapped). The speed is one signal of one frame, defined the way a DBC file writes it —
the RAV4's is `SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h"` in message 0xB4 — and this
module turns such a definition plus the frame's bytes into the physical value. It does no
I/O: the bus or recording that delivers frames is an adapter's job, and document validation
calls `check` to report a definition that cannot fit a frame, with the file, line and column
it knows.

The definition itself, `check` and DBC's bit numbering are schema (schemas/signal.py);
reading one out of a DBC file with cantools is an adapter's (adapters/can/dbc.py).

`decode` runs on every speed frame of a Raspberry Pi, so it is a few integer operations on
the frame's bytes.
"""

from __future__ import annotations

from schemas.signal import MAX_FRAME_ID as MAX_FRAME_ID
from schemas.signal import MAX_LENGTH as MAX_LENGTH
from schemas.signal import RAV4_SPEED as RAV4_SPEED
from schemas.signal import ByteOrder as ByteOrder
from schemas.signal import SignalDef as SignalDef
from schemas.signal import check as check
from schemas.signal import end as _end


def raw(sig: SignalDef, data: bytes) -> int | None:
    """The signal's raw integer in `data` (signed if the signal is), or None when the frame
    is too short to hold it. `sig` must pass `check`."""
    if len(data) * 8 < _end(sig):
        return None
    mask = (1 << sig.length) - 1
    if sig.byte_order == "little_endian":
        value = (int.from_bytes(data, "little") >> sig.start_bit) & mask
    else:
        value = (int.from_bytes(data, "big") >> (len(data) * 8 - _end(sig))) & mask
    if sig.signed and value >> (sig.length - 1):
        value -= 1 << sig.length
    return value


def decode(sig: SignalDef, data: bytes) -> float | None:
    """The signal's physical value in `data` (km/h for the RAV4's speed), or None when the
    frame is too short to hold it: "no signal", which a gate treats as unknown."""
    value = raw(sig, data)
    if value is None:
        return None
    scale, offset = float(sig.scale), float(sig.offset)
    if scale.is_integer() and offset.is_integer():
        # Exact in integers, rounded once: a 64-bit counter keeps its value as cantools does.
        return float(value * int(scale) + int(offset))
    return value * scale + offset
