"""A socketcand server for tests: a drive (its frames) replayed onto loopback TCP, in the
protocol python-can's `socketcand` interface speaks.

The kernel here has no SocketCAN, so the real daemon cannot run; this stands in for it as
a bus shared by every connected client, in the rawmode subset python-can 4.6 uses:

    server: < hi >
    client: < open can0 >       server: < ok >    (< error … > for a bus it does not serve)
    client: < rawmode >         server: < ok >
    server: < frame 0B4 1700000000.123456 000000006000001C >     every frame on the bus
    client: < send 0B4 8 0 0 0 0 60 0 0 1c >                     a frame put on the bus

Frames are replayed at the recording's pace (times `speed`) from `offset` seconds into it,
stamped with the wall-clock time they are sent, as socketcand stamps frames on reception. A
frame a client sends goes to every other client, as on a real bus (SocketCAN does not echo
a socket's own frames to it). Everything binds to 127.0.0.1, every thread waits at most a
fraction of a second at a time, and the `with` block's end stops it all.

Run as a process: `python -m tests.socketcand LOG --offset S --port P`; it prints
`listening 127.0.0.1:PORT` once it accepts clients and stops on SIGTERM or SIGINT.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

import can

# python-can reads each handshake answer with a single recv() and compares it whole: a
# frame sent right behind "< ok >" would arrive glued to it and fail the handshake.
RAWMODE_SETTLE = 0.05
TICK = 0.1  # the longest any thread waits before it looks at the stop flag again


def frame_text(msg: can.Message, stamp: float) -> str:
    """`msg` as socketcand sends a received frame."""
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    return f"< frame {ident} {stamp:.6f} {bytes(msg.data).hex().upper()} >"


def parse_send(command: str) -> can.Message | None:
    """The frame of a client's `< send ID LEN B… >` (bytes in hex, not zero-padded)."""
    parts = command.removeprefix("<").removesuffix(">").split()
    if len(parts) < 3 or parts[0] != "send":
        return None
    try:
        ident, length, data = int(parts[1], 16), int(parts[2], 16), bytes(
            int(b, 16) for b in parts[3:])
    except ValueError:
        return None
    if length != len(data):
        return None
    return can.Message(arbitration_id=ident, is_extended_id=len(parts[1]) > 3, data=data,
                       dlc=length, timestamp=time.time())


class _Client:
    def __init__(self, conn: socket.socket) -> None:
        self.conn = conn
        self.raw = False  # frames flow only once rawmode is answered
        self.opened = False
        self._lock = threading.Lock()

    def send(self, text: str) -> bool:
        with self._lock:
            try:
                self.conn.sendall(text.encode("ascii"))
                return True
            except OSError:  # gone, or too slow to take a frame in TICK: dropped
                return False


class SocketcandServer:
    """Serves bus `channel` on 127.0.0.1:`port` (0: a free port), replaying `frames`."""

    def __init__(self, frames: Sequence[can.Message], *, offset: float = 0.0,
                 speed: float = 1.0, channel: str = "can0", port: int = 0,
                 wait_for_client: bool = False) -> None:
        start = frames[0].timestamp + offset if frames else 0.0
        self.frames = [m for m in frames if m.timestamp >= start]
        self.speed = speed
        self.wait_for_client = wait_for_client  # the replay begins once a client listens
        self.channel = channel
        self.replayed = 0       # frames put on the bus by the replay so far
        self.received: list[can.Message] = []  # frames clients sent
        self._stop = threading.Event()
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(("127.0.0.1", port))
        self.port = int(self._listener.getsockname()[1])
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []

    def config(self) -> dict[str, Any]:
        """What lpam's desired state would say in `vehicle.source.bus`."""
        return {"interface": "socketcand", "host": "127.0.0.1", "port": self.port,
                "channel": self.channel}

    def __enter__(self) -> SocketcandServer:
        self._listener.listen(16)
        self._listener.settimeout(TICK)
        self._start(self._accept)
        self._start(self._replay)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def stop(self) -> None:
        """Hang up on every client and stop; idempotent."""
        self._stop.set()
        with contextlib.suppress(OSError):
            self._listener.close()
        for client in self._snapshot():
            with contextlib.suppress(OSError):
                client.conn.shutdown(socket.SHUT_RDWR)
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2)

    def inject(self, text: str) -> None:
        """Send `text` as it is to every client in rawmode (a garbled frame, say)."""
        for client in self._snapshot():
            if client.raw:
                client.send(text)

    def _start(self, target: Callable[..., None], *args: object) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _snapshot(self) -> list[_Client]:
        with self._lock:
            return list(self._clients)

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except (socket.timeout, TimeoutError):  # one class since 3.10; not on 3.9
                continue
            except OSError:
                return
            conn.settimeout(TICK)
            client = _Client(conn)
            with self._lock:
                self._clients.append(client)
            self._start(self._serve, client)

    def _replay(self) -> None:
        if not self.frames:
            return
        while self.wait_for_client and not any(c.raw for c in self._snapshot()):
            if self._stop.wait(0.01):
                return
        began, first = time.monotonic(), self.frames[0].timestamp
        for msg in self.frames:
            due = began + (msg.timestamp - first) / self.speed
            while (left := due - time.monotonic()) > 0:
                if self._stop.wait(min(left, TICK)):
                    return
            if self._stop.is_set():
                return
            self._broadcast(frame_text(msg, time.time()), sender=None)
            self.replayed += 1

    def _broadcast(self, text: str, *, sender: _Client | None) -> None:
        for client in self._snapshot():
            if client.raw and client is not sender and not client.send(text):
                self._drop(client)

    def _drop(self, client: _Client) -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)
        with contextlib.suppress(OSError):
            client.conn.shutdown(socket.SHUT_RDWR)

    def _serve(self, client: _Client) -> None:
        buffer = ""
        try:
            if not client.send("< hi >"):
                return
            while not self._stop.is_set():
                try:
                    data = client.conn.recv(4096)
                except (socket.timeout, TimeoutError):  # one class since 3.10; not on 3.9
                    continue
                except OSError:
                    return
                if not data:
                    return
                buffer += data.decode("ascii", errors="replace")
                while (end := buffer.find(">")) >= 0:
                    command, buffer = buffer[: end + 1].strip(), buffer[end + 1:]
                    self._command(client, command)
                if len(buffer) > 4096:  # no command is this long
                    return
        finally:
            self._drop(client)
            client.conn.close()

    def _command(self, client: _Client, command: str) -> None:
        words = command.removeprefix("<").removesuffix(">").split()
        verb = words[0] if words else ""
        if verb == "open":
            client.opened = words[1:] == [self.channel]
            client.send("< ok >" if client.opened else "< error could not open bus >")
        elif verb == "rawmode" and client.opened:
            client.send("< ok >")
            time.sleep(RAWMODE_SETTLE)
            client.raw = True
        elif verb == "send" and client.raw:
            msg = parse_send(command)
            if msg is None:
                client.send("< error bad send >")
                return
            self.received.append(msg)
            self._broadcast(frame_text(msg, time.time()), sender=client)
        elif verb == "echo":
            client.send("< echo >")
        else:
            client.send("< error unknown command >")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.socketcand")
    parser.add_argument("log", type=Path, help="a candump -l log to replay (.gz too)")
    parser.add_argument("--offset", type=float, default=0.0, help="seconds into the log")
    parser.add_argument("--port", type=int, default=0, help="0: a free port")
    parser.add_argument("--speed", type=float, default=1.0, help="replay pace factor")
    parser.add_argument("--channel", default="can0")
    args = parser.parse_args(argv)
    from tests.canlog import read_log

    frames = read_log(args.log)
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    with SocketcandServer(frames, offset=args.offset, speed=args.speed,
                          channel=args.channel, port=args.port) as server:
        print(f"listening 127.0.0.1:{server.port}", flush=True)
        while not stop.wait(TICK):
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
