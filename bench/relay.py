"""A counting TCP relay on 127.0.0.1: what a client and a server send each other, in bytes.

    with Relay(upstream_port) as relay:      # listens on relay.port, forwards to upstream
        mark = relay.mark()
        ... a client connects to 127.0.0.1:relay.port ...
        traffic = relay.since(mark)          # waits for those connections to close

It reads nothing of what passes through: it copies bytes both ways, per connection, and
counts the TCP payload (no IP or TCP headers) server→client and client→server. So any
client can be measured the same way, whatever protocol version or library it speaks.
Threads only, inside the benchmark's own process: there is no process to kill, and the
listening socket and every connection are closed on the way out.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from dataclasses import dataclass
from types import TracebackType

CHUNK = 65536


@dataclass
class Connection:
    to_client: int = 0  # bytes server→client
    to_server: int = 0  # bytes client→server
    open_pumps: int = 2  # one per direction; the connection is over at 0


@dataclass(frozen=True)
class Traffic:
    connections: int
    to_client: int
    to_server: int


class Relay:
    """Accepts on a free loopback port and forwards each connection to `upstream_port`."""

    def __init__(self, upstream_port: int) -> None:
        self.upstream_port = upstream_port
        self.port = 0
        self._lock = threading.Condition()
        self._conns: list[Connection] = []
        self._sockets: list[socket.socket] = []
        self._stop = threading.Event()
        self._listener: socket.socket | None = None
        self._acceptor: threading.Thread | None = None

    def __enter__(self) -> Relay:
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.bind(("127.0.0.1", 0))
        listener.listen(64)
        listener.settimeout(0.2)  # so that the accept loop sees the stop flag
        self._listener = listener
        self.port = int(listener.getsockname()[1])
        self._acceptor = threading.Thread(target=self._accept, name="relay-accept", daemon=True)
        self._acceptor.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        if self._acceptor is not None:
            self._acceptor.join(timeout=5)
        with self._lock:
            for sock in [*self._sockets, *([self._listener] if self._listener else [])]:
                with contextlib.suppress(OSError):
                    sock.close()

    def url(self, name: str) -> str:
        return f"git://127.0.0.1:{self.port}/{name}"

    def mark(self) -> int:
        """How many connections were accepted so far (the start of a measurement)."""
        with self._lock:
            return len(self._conns)

    def since(self, mark: int, *, timeout: float = 10.0) -> Traffic:
        """The traffic of every connection accepted after `mark`, once all of them closed."""
        deadline = time.monotonic() + timeout
        with self._lock:
            while any(c.open_pumps for c in self._conns[mark:]):
                left = deadline - time.monotonic()
                if left <= 0:
                    raise RuntimeError("relay: a connection stayed open after its client ended")
                self._lock.wait(left)
            conns = self._conns[mark:]
            return Traffic(len(conns), sum(c.to_client for c in conns),
                           sum(c.to_server for c in conns))

    def _accept(self) -> None:
        assert self._listener is not None
        while not self._stop.is_set():
            try:
                client, _ = self._listener.accept()
            except socket.timeout:  # an alias of TimeoutError from 3.10 on; 3.9 needs this
                continue
            except OSError:
                return
            client.settimeout(None)
            try:
                server = socket.create_connection(("127.0.0.1", self.upstream_port))
            except OSError:
                client.close()  # the client sees a closed connection, as with no server
                continue
            conn = Connection()
            with self._lock:
                self._conns.append(conn)
                self._sockets += [client, server]
            for src, dst, to_client in ((server, client, True), (client, server, False)):
                threading.Thread(target=self._pump, args=(src, dst, conn, to_client),
                                 name="relay-pump", daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, conn: Connection,
              to_client: bool) -> None:
        """Copy one direction until its sender closes (or resets), then pass the close on."""
        try:
            while True:
                data = src.recv(CHUNK)
                if not data:
                    break
                dst.sendall(data)
                with self._lock:
                    if to_client:
                        conn.to_client += len(data)
                    else:
                        conn.to_server += len(data)
        except OSError:
            pass
        with contextlib.suppress(OSError):
            dst.shutdown(socket.SHUT_WR)
        with self._lock:
            conn.open_pumps -= 1
            if not conn.open_pumps:
                for sock in (src, dst):
                    with contextlib.suppress(OSError):
                        sock.close()
                    with contextlib.suppress(ValueError):
                        self._sockets.remove(sock)
            self._lock.notify_all()
