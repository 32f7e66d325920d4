"""A signal read out of a DBC file with cantools: the definition of the vehicle's speed
when a desired state names `dbc:` and `signal:` instead of writing the DBC line inline.

It reads a file, so it is an adapter; the definition it returns is pure (schemas/signal.py).
cantools is imported only when a DBC file is named (importing it costs a noticeable fraction
of a second on a Raspberry Pi).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import ConfigError, shorten
from schemas.signal import SignalDef, check
from schemas.vehicle import SignalSpec

if TYPE_CHECKING:
    from cantools.database.can import Database, Message, Signal

# Imported inside functions: cantools (and python-can under it) loads only for a gate configured
# from a DBC file: an optional dependency present on a car, and ~180 modules of start-up.

NAMES_SHOWN = 12


def speed_definition(spec: SignalSpec, base_dir: Path) -> SignalDef:
    """The decodable signal of `spec`; a DBC file (relative to `base_dir`, the desired
    state's folder) is read now, ConfigError if it cannot be."""
    if spec.dbc is None:
        return spec.inline()
    assert spec.signal is not None
    path = Path(spec.dbc)
    return from_dbc(path if path.is_absolute() else base_dir / path,
                    message=spec.message, signal=spec.signal)


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
