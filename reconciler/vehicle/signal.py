"""One signal read out of one CAN frame: the pure core of the "is the car parked?" gate.

Before a cutover lpam asks the vehicle's speed (a car that moves must never have its control
app swapped). The speed is one signal of one frame, defined the way a DBC file writes it —
the RAV4's is `SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h"` in message 0xB4 — and this
module turns such a definition plus the frame's bytes into the physical value. It does no
I/O: the bus or recording that delivers frames is an adapter's job, and document validation
calls `check` to report a definition that cannot fit a frame, with the file, line and column
it knows.

DBC's bit numbering, which `SignalDef.start_bit` keeps unchanged (as cantools does):
- `@1` little-endian (Intel): the start bit is the signal's least significant bit, bit `b`
  being bit `b % 8` of byte `b // 8`, and the signal grows towards higher bits and bytes.
- `@0` big-endian (Motorola): the start bit is the signal's *most* significant bit in the
  same "sawtooth" numbering (bit 7 of byte 0 is 7, bit 0 of byte 1 is 8), and the signal
  grows towards the less significant bits, then on to the next byte's bit 7.

`decode` runs on every speed frame of a Raspberry Pi, so it is a few integer operations on
the frame's bytes; cantools, which can read a DBC file, is imported only by `from_dbc`
(importing it costs a noticeable fraction of a second).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from reconciler.errors import ConfigError, shorten

if TYPE_CHECKING:
    from cantools.database.can import Database, Message, Signal

ByteOrder = Literal["big_endian", "little_endian"]

MAX_FRAME_ID = (1 << 29) - 1  # an extended (29-bit) CAN identifier
MAX_LENGTH = 64
NAMES_SHOWN = 12


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
    if _end(sig) > bits:
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


def _end(sig: SignalDef) -> int:
    """One past the signal's last bit, counted in the frame's own order: from bit 0 of byte
    0 upwards (little-endian), or from bit 7 of byte 0 downwards (big-endian)."""
    if sig.byte_order == "little_endian":
        return sig.start_bit + sig.length
    msb = (sig.start_bit // 8) * 8 + 7 - sig.start_bit % 8
    return msb + sig.length


def from_dbc(path: Path, *, message: str | int | None, signal: str) -> SignalDef:
    """The signal `signal` of a DBC file, in the message named or numbered `message` (or
    the one message that has such a signal, when None). Every way this can go wrong is a
    `ConfigError` naming the file and what to do."""
    # Only a gate configured from a DBC file pays for these imports.
    import cantools.database
    from cantools.database.errors import UnsupportedDatabaseFormatError

    try:
        db = cantools.database.load_file(path, database_format="dbc", strict=False)
    except OSError as exc:
        raise ConfigError(f"cannot read the DBC file: {exc.strerror}", path=path,
                          hint="give the path of an existing, readable .dbc file") from None
    except UnsupportedDatabaseFormatError as exc:
        cause = exc.e_dbc if exc.e_dbc is not None else exc
        line, column = getattr(cause, "line", None), getattr(cause, "column", None)
        text = _first_line(cause)
        if line is not None:  # the error's place is already in file:line:col
            text = text.replace(f" at line {line}, column {column}", "", 1)
        raise ConfigError(f"not a DBC file cantools can read: {text}", path=path,
                          line=line, column=column,
                          hint="fix the DBC file there, or use the vehicle's file from opendbc"
                          ) from None
    except Exception as exc:  # cantools lets some malformed files escape as other errors
        raise ConfigError(f"not a DBC file cantools can read: {_first_line(exc)}",
                          path=path, hint="check the DBC file, or use the vehicle's file "
                          "from opendbc") from None
    if not isinstance(db, cantools.database.can.Database):
        raise ConfigError("not a CAN database", path=path, hint="give a .dbc file")
    msg = _message(db, path, message, signal)
    sig = _signal(msg, path, signal)
    definition = SignalDef(
        frame_id=msg.frame_id, start_bit=sig.start, length=sig.length,
        byte_order=sig.byte_order, signed=sig.is_signed, scale=float(sig.scale),
        offset=float(sig.offset), name=sig.name)
    problem = check(definition)
    if problem is not None:
        raise ConfigError(problem, path=path,
                          hint="lpam reads signals of classic 8-byte CAN frames only")
    return definition


def _message(db: Database, path: Path, message: str | int | None, signal: str) -> Message:
    if message is None:
        having = [m for m in db.messages if any(s.name == signal for s in m.signals)]
        if len(having) == 1:
            return having[0]
        if not having:
            raise ConfigError(f"no message has a signal {signal}", path=path,
                              hint=f"name a signal of the file: {_signal_names(db)}")
        raise ConfigError(
            f"signal {signal} is in {len(having)} messages: {_message_names(having)}",
            path=path, hint="name the message (its name or frame id) as well")
    try:
        if isinstance(message, int):
            return db.get_message_by_frame_id(message)
        return db.get_message_by_name(message)
    except KeyError:
        shown = f"{message:#x}" if isinstance(message, int) else message
        raise ConfigError(f"no message {shown}", path=path,
                          hint=f"name one of: {_message_names(db.messages)}") from None


def _signal(msg: Message, path: Path, signal: str) -> Signal:
    try:
        sig = msg.get_signal_by_name(signal)
    except KeyError:
        names = _listed([s.name for s in msg.signals]) or "(it has no signals)"
        raise ConfigError(f"message {msg.name} has no signal {signal}", path=path,
                          hint=f"name one of: {names}") from None
    if sig.multiplexer_ids is not None:
        raise ConfigError(
            f"signal {signal} of message {msg.name} is multiplexed (present only when "
            f"{sig.multiplexer_signal} is {_listed([str(i) for i in sig.multiplexer_ids])})",
            path=path, hint="lpam cannot follow a multiplexer; choose a plain signal")
    if sig.is_float:
        raise ConfigError(f"signal {signal} of message {msg.name} is an IEEE float",
                          path=path, hint="lpam reads integer signals only; choose another")
    return sig


def _message_names(messages: list[Message]) -> str:
    return _listed([f"{m.name} ({m.frame_id:#x})" for m in messages]) or "(the file has none)"


def _signal_names(db: Database) -> str:
    return _listed(sorted({s.name for m in db.messages for s in m.signals})) or "(none)"


def _listed(names: list[str]) -> str:
    if len(names) <= NAMES_SHOWN:
        return ", ".join(names)
    return ", ".join(names[:NAMES_SHOWN]) + f" … ({len(names)} in all)"


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return shorten(text.splitlines()[0], 200)
