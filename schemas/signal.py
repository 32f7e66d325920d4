"""Where one signal sits in a CAN frame, as a DBC line writes it, and whether it fits one.

The RAV4's speed is `SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h"` in message 0xB4. This
is the definition a desired state's `vehicle.speed` declares (schemas/vehicle.py) and that
`check` validates with the document; decoding frames with it is the vehicle's business
(reconciler/core/vehicle/signal.py), and reading one out of a DBC file an adapter's
(reconciler/adapters/can/dbc.py). Pure: no I/O, nothing but arithmetic on the definition.

DBC's bit numbering, which `SignalDef.start_bit` keeps unchanged (as cantools does):
- `@1` little-endian (Intel): the start bit is the signal's least significant bit, bit `b`
  being bit `b % 8` of byte `b // 8`, and the signal grows towards higher bits and bytes.
- `@0` big-endian (Motorola): the start bit is the signal's *most* significant bit in the
  same "sawtooth" numbering (bit 7 of byte 0 is 7, bit 0 of byte 1 is 8), and the signal
  grows towards the less significant bits, then on to the next byte's bit 7.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

ByteOrder = Literal["big_endian", "little_endian"]

MAX_FRAME_ID = (1 << 29) - 1  # an extended (29-bit) CAN identifier
MAX_LENGTH = 64


@dataclass(frozen=True)
class SignalDef:
    """Where one signal sits in a frame and how its raw bits become a physical value:
    `raw * scale + offset`, the raw bits read as two's complement when `signed`."""

    frame_id: int
    start_bit: int
    length: int
    byte_order: ByteOrder
    signed: bool = False
    scale: float = 1.0
    offset: float = 0.0
    name: str = "SPEED"


# opendbc `_toyota_2017.dbc`: BO_ 180 SPEED, SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h".
RAV4_SPEED = SignalDef(0xB4, 47, 16, "big_endian", False, 0.01, 0.0, "SPEED")


def check(sig: SignalDef, frame_bytes: int = 8) -> str | None:
    """Why `sig` cannot be read from a frame of `frame_bytes` bytes, as one sentence that
    says what to fix; None when it fits. Validation adds where the definition was written."""
    bits = 8 * frame_bytes
    name = sig.name
    if not 0 <= sig.frame_id <= MAX_FRAME_ID:
        return (f"frame id {sig.frame_id:#x} of signal {name} does not fit the 29 bits of a "
                f"CAN id; use the message's id, 0 to {MAX_FRAME_ID:#x}")
    if sig.byte_order not in ("big_endian", "little_endian"):
        return (f"byte order {sig.byte_order!r} of signal {name} is unknown; "
                "use big_endian (DBC @0) or little_endian (DBC @1)")
    if not 0 <= sig.start_bit < bits:
        return (f"start bit {sig.start_bit} of signal {name} is outside a {frame_bytes}-byte "
                f"frame; use a start bit from 0 to {bits - 1}")
    if not 1 <= sig.length <= MAX_LENGTH:
        return (f"length {sig.length} of signal {name} is not possible; "
                f"use 1 to {MAX_LENGTH} bits")
    if end(sig) > bits:
        return (f"signal {name} ({sig.length} bits from start bit {sig.start_bit}, "
                f"{sig.byte_order.replace('_', '-')}) runs past the end of a "
                f"{frame_bytes}-byte frame; check the start bit, the length and the byte "
                "order (in a DBC, @0 is big-endian and its start bit is the most significant "
                "bit, @1 is little-endian and its start bit is the least significant bit)")
    if not (math.isfinite(sig.scale) and math.isfinite(sig.offset)):
        return f"scale and offset of signal {name} must be finite numbers"
    if sig.scale == 0:
        # Every frame would read as the offset: a speed gate would see a car forever parked.
        return f"scale 0 of signal {name} makes every frame read the same; use the DBC's factor"
    return None


def end(sig: SignalDef) -> int:
    """One past the signal's last bit, counted in the frame's own order: from bit 0 of byte
    0 upwards (little-endian), or from bit 7 of byte 0 downwards (big-endian)."""
    if sig.byte_order == "little_endian":
        return sig.start_bit + sig.length
    msb = (sig.start_bit // 8) * 8 + 7 - sig.start_bit % 8
    return msb + sig.length
