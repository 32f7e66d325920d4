"""Where an update gate gets CAN frames: a live bus, the recording followed as it grows, or
a log file, behind one `FrameSource` protocol.

Place in the flow: before a cutover, a gate asks whether the vehicle stands still. It opens
the source `vehicle.source` names (`open_source`), takes the last seconds already recorded
(`backlog`), listens a little longer (`frames`) and decodes the speed from what it got.
Opening faults, and a recording that cannot be read (permission denied, an I/O error), are
a `VehicleSourceError` that names the source and what to do (a gate shows it as "no
signal", with that reason); a fault while listening (the file vanished, the bus went away)
ends the stream quietly, and the gate reads that silence as "no signal", never as a
standing car. No python-can exception or traceback leaves this module. python-can is
imported only once a source is opened.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import stat
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from reconciler.base.errors import VehicleSourceError

if TYPE_CHECKING:
    import can

    from reconciler.adapters.can.csvlog import Follower, LineFormat

# Imported inside functions: python-can (csvlog pulls it too) loads only when a bus or log is
# opened: an optional dependency present on a car, and ~165 modules of start-up.

OPEN_TIMEOUT = 5.0   # seconds a bus may take to connect and answer its handshake
RECV_SLICE = 0.25    # longest single wait in bus.recv: deadlines are kept, hangups seen
_SOURCE_HINT = "is the recording app running? set vehicle.source (bus, follow or log)"


class FrameSource(Protocol):
    """CAN frames from somewhere, for a gate. Frames are python-can `Message`s."""

    @property
    def description(self) -> str:
        """For humans: "socketcand can0 at 127.0.0.1:29536", "follow A → B", "log X"."""
        ...

    @property
    def skipped(self) -> int:
        """Malformed rows or lines skipped so far."""
        ...

    def backlog(self, seconds: float) -> list[can.Message]:
        """Frames already recorded within `seconds` of the newest one, oldest first; a bus
        has no history and returns []."""
        ...

    def frames(self, deadline: float) -> Iterator[can.Message]:
        """New frames as they arrive, until time.monotonic() >= deadline."""
        ...

    def close(self) -> None: ...


def open_source(
    *, bus: Mapping[str, Any] | None = None, follow: Path | None = None,
    log: Path | None = None, timeout: float = OPEN_TIMEOUT,
) -> FrameSource:
    """Open the one source given: `bus` is passed to python-can as `can.Bus(**bus)`,
    `follow` is a libpanda CSV (or the symlink to it), `log` a file python-can reads."""
    given = [name for name, value in (("bus", bus), ("follow", follow), ("log", log))
             if value is not None]
    _quiet()
    if len(given) != 1:
        raise VehicleSourceError(
            f"vehicle.source needs exactly one of bus, follow or log, not "
            f"{' and '.join(given) or 'none'}",
            hint="e.g. follow: /etc/libpanda.d/currentCan.csv")
    if bus is not None:
        return BusSource.open(bus, timeout=timeout)
    if follow is not None:
        return _open_follow(Path(follow))
    assert log is not None
    return _open_log(Path(log))


class BusSource:
    """A live bus through python-can: no history, frames as `recv` returns them. Frames the
    interface cannot parse are dropped by python-can before they get here (`skipped` stays
    0); a bus that fails while listening is silent from then on."""

    skipped = 0

    def __init__(self, bus: can.BusABC, description: str) -> None:
        self._bus = bus
        self.description = description
        self._failed = False

    @classmethod
    def open(cls, config: Mapping[str, Any], *, timeout: float) -> BusSource:
        config = dict(config)
        description = _bus_description(config)
        import can

        interface = config.get("interface")
        valid = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
        if not interface:
            raise VehicleSourceError(
                f"{description}: vehicle.source.bus names no interface",
                hint=f"add interface: one of {valid}")
        if interface not in can.interfaces.VALID_INTERFACES:
            raise VehicleSourceError(
                f"{description}: python-can has no interface {interface!r}",
                hint=f"use one of {valid}")
        if interface == "socketcand":
            _reach(description, config, timeout)
        return cls(_within(timeout, description, lambda: can.Bus(**config)), description)

    def backlog(self, seconds: float) -> list[can.Message]:
        return []

    def frames(self, deadline: float) -> Iterator[can.Message]:
        while not self._failed and (left := deadline - time.monotonic()) > 0:
            if _socketcand_closed(self._bus):
                # python-can's socketcand client would spin at full CPU until the deadline
                self._failed = True
                break
            try:
                msg = self._bus.recv(timeout=min(left, RECV_SLICE))
            except Exception:  # python-can raises CanError, OSError or worse from a driver
                self._failed = True
                break
            if msg is not None:
                yield msg
        _sleep_until(deadline)

    def close(self) -> None:
        with contextlib.suppress(Exception):  # a failed bus may fail to shut down too
            self._bus.shutdown()


class FileSource:
    """A text recording — libpanda CSV or candump log — read back from its end, then
    followed as it grows (see `csvlog.Follower`)."""

    def __init__(self, follower: Follower, label: Callable[[Follower], str]) -> None:
        self._follower = follower
        self._label = label

    @property
    def description(self) -> str:
        return self._label(self._follower)

    @property
    def skipped(self) -> int:
        return self._follower.skipped

    def backlog(self, seconds: float) -> list[can.Message]:
        return self._follower.backlog(seconds)

    def frames(self, deadline: float) -> Iterator[can.Message]:
        return self._follower.frames(deadline)

    def close(self) -> None:
        self._follower.close()


class RecordedSource:
    """A log only python-can's readers can read, and only as a whole (.asc, .blf, .trc,
    .mf4, .db, python-can's own .csv, gzipped logs): their readers keep state from the
    file's start, so a line cannot be read alone. `backlog` reads the file through once,
    keeping only the window; `frames` yields nothing new — these files are not followed
    as they grow (record a candump .log or follow libpanda's CSV for that)."""

    skipped = 0

    def __init__(self, path: Path) -> None:
        self.path = path
        self.description = f"log {path}"

    def backlog(self, seconds: float) -> list[can.Message]:
        import can

        window: deque[can.Message] = deque()
        newest = float("-inf")
        try:
            with can.LogReader(self.path) as reader:
                for msg in reader:
                    window.append(msg)
                    newest = max(newest, msg.timestamp)
                    while window[0].timestamp < newest - seconds:
                        window.popleft()
        except OSError as exc:
            if exc.errno is not None:  # the file cannot be read: not a damaged record
                raise _file_error(self.path, exc) from None
            self.skipped += 1  # gzip's BadGzipFile, an OSError without errno: damage
        except Exception:  # a damaged record ends the log here; what came before counts
            self.skipped += 1
        return [msg for msg in window if msg.timestamp >= newest - seconds]

    def frames(self, deadline: float) -> Iterator[can.Message]:
        _sleep_until(deadline)
        yield from ()

    def close(self) -> None:
        pass


def _open_follow(path: Path) -> FileSource:
    from reconciler.adapters.can.csvlog import LIBPANDA

    follower = _follower(path, LIBPANDA)

    def label(f: Follower) -> str:
        return f"follow {f.path} → {f.current}" if f.path.is_symlink() else f"follow {f.path}"

    return FileSource(follower, label)


def _open_log(path: Path) -> FileSource | RecordedSource:
    from reconciler.adapters.can.csvlog import CANDUMP, HEADER, LIBPANDA

    _check_file(path)
    if _first_line(path) == HEADER:  # libpanda's CSV given as a log is read as one
        return FileSource(_follower(path, LIBPANDA), lambda f: f"log {f.path} (libpanda CSV)")
    if path.suffix.lower() == ".log":
        return FileSource(_follower(path, CANDUMP), lambda f: f"log {f.path}")
    import can

    try:
        can.LogReader(path).stop()
    except Exception as exc:  # also a reader that trips on the file's header
        if isinstance(exc, ValueError) and "unknown log format" in str(exc):
            kinds = ", ".join(sorted(can.io.MESSAGE_READERS))
            raise VehicleSourceError(
                f"log {path}: python-can reads no {path.suffix or 'suffix-less'} files",
                hint=f"give a log ending in one of {kinds} (a candump log ends in .log), or "
                     "follow: a libpanda CSV") from None
        raise VehicleSourceError(f"log {path}: python-can cannot read it: {_line(exc)}",
                                 hint="check that the file is a complete log") from None
    return RecordedSource(path)


def _follower(path: Path, fmt: LineFormat) -> Follower:
    from reconciler.adapters.can.csvlog import Follower

    _check_file(path)
    try:
        return Follower(path, fmt)
    except OSError as exc:
        raise _file_error(path, exc) from None


def _check_file(path: Path) -> None:
    """Raise for a recording that is not there or is a folder (opening it tells whether
    lpam may read it)."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise _file_error(path, exc) from None
    if stat.S_ISDIR(info.st_mode):
        raise VehicleSourceError(
            f"{path} is a directory, not a recording",
            hint="name the file itself, e.g. follow: /etc/libpanda.d/currentCan.csv")


def _file_error(path: Path, exc: OSError) -> VehicleSourceError:
    if isinstance(exc, FileNotFoundError):
        if os.path.islink(path):
            return VehicleSourceError(
                f"no such file: {path} points to {os.readlink(path)}, which does not exist",
                hint=_SOURCE_HINT)
        return VehicleSourceError(f"no such file: {path}", hint=_SOURCE_HINT)
    if isinstance(exc, PermissionError):
        return VehicleSourceError(
            f"cannot read {path}: permission denied",
            hint="run lpam as a user that may read the recording, or let the recording app "
                 "write it readable (its folders too)")
    return VehicleSourceError(f"cannot read {path}: {exc.strerror or exc}", hint=_SOURCE_HINT)


def _first_line(path: Path) -> str:
    try:
        with open(path, "rb") as file:
            return file.readline(256).decode("utf-8", errors="replace").strip()
    except OSError as exc:
        raise _file_error(path, exc) from None


def _bus_description(config: Mapping[str, Any]) -> str:
    text = f"{config.get('interface', 'bus')} {config.get('channel', '')}".strip()
    if "host" in config or "port" in config:
        text += f" at {config.get('host', '?')}:{config.get('port', '?')}"
    return text


def _reach(description: str, config: Mapping[str, Any], timeout: float) -> None:
    """Fail fast when nothing listens: python-can's socketcand client retries a refused
    connection in a busy loop for 10 s before it gives up."""
    host, port = config.get("host"), config.get("port")
    if not isinstance(host, str) or not isinstance(port, int):
        raise VehicleSourceError(
            f"{description}: socketcand needs a host (text) and a port (number)",
            hint="e.g. bus: {interface: socketcand, host: 127.0.0.1, port: 29536, "
                 "channel: can0}")
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise VehicleSourceError(
            f"{description}: cannot connect: {exc.strerror or exc}",
            hint="is socketcand running there? check vehicle.source.bus") from None


def _within(timeout: float, description: str, make: Callable[[], can.BusABC]) -> can.BusABC:
    """`make()` in a helper thread, for at most `timeout` seconds: python-can's clients
    wait without limit for a server that accepts and then says nothing. A bus that comes
    up after the caller gave up is shut down at once."""
    done = threading.Event()
    outcome: list[can.BusABC | BaseException] = []
    lock = threading.Lock()

    def run() -> None:
        try:
            result: can.BusABC | BaseException = make()
        except BaseException as exc:
            result = exc
        with lock:
            abandoned = done.is_set()
            outcome.append(result)
            done.set()
        if abandoned and not isinstance(result, BaseException):
            with contextlib.suppress(Exception):  # nobody is left to tell
                result.shutdown()

    threading.Thread(target=run, name="lpam-can-open", daemon=True).start()
    finished = done.wait(timeout)
    with lock:
        if not finished:
            done.set()  # from here on, the helper cleans up after itself
            raise VehicleSourceError(
                f"{description}: no answer within {timeout:g} s",
                hint="is the right server at that address? check vehicle.source.bus")
    result = outcome[0]
    if isinstance(result, BaseException):
        raise _bus_error(description, result) from None
    return result


def _bus_error(description: str, exc: BaseException) -> VehicleSourceError:
    import can

    valid = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
    if isinstance(exc, can.CanInterfaceNotImplementedError):
        return VehicleSourceError(f"{description}: interface not available here: {_line(exc)}",
                                  hint=f"python-can's interfaces are {valid}; some need "
                                       "a driver or a package installed")
    if isinstance(exc, TypeError):
        return VehicleSourceError(
            f"{description}: bad setting in vehicle.source.bus: {_line(exc)}",
            hint="see python-can's documentation of that interface")
    return VehicleSourceError(f"{description}: cannot open the bus: {_line(exc)}",
                              hint="check vehicle.source.bus and that the bus is up")


def _line(exc: BaseException) -> str:
    """The first line of an exception's text: python-can puts whole tracebacks in some."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _socketcand_closed(bus: can.BusABC) -> bool:
    """True when a socketcand server has closed the connection. python-can's client does
    not notice (select says readable, recv gives b"", it returns None and is called again
    at once); its socket is private, hence the name-mangled attribute."""
    sock = getattr(bus, "_SocketCanDaemonBus__socket", None)
    if not isinstance(sock, socket.socket):
        return False
    try:
        return sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True


def _quiet() -> None:
    """Keep python-can's log records off the terminal. It logs a warning whenever a TCP
    read ends inside a socketcand message, and the traceback of every receive error; with
    no handler of lpam's on the way, Python's last-resort handler prints them to stderr.
    They still reach any handler lpam puts on the root logger (its debug log)."""
    logger = logging.getLogger("can")
    if not any(isinstance(h, logging.NullHandler) for h in logger.handlers):
        logger.addHandler(logging.NullHandler())


def _sleep_until(deadline: float) -> None:
    time.sleep(max(0.0, deadline - time.monotonic()))
