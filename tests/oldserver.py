"""A git server of the old protocol only: a relay in front of a real `git daemon` that
drops the client's request for protocol v2 from the first line of each connection.

Why: protocol v2 lets a client ask for any commit by its hash, so against a modern
`git daemon` (or GitHub) lpam's one-commit fetch always succeeds. Servers that speak only
v0 (old git, some hosting) grant a commit by hash only when it is a branch or tag tip,
unless `uploadpack.allowReachableSHA1InWant` is set: lpam must then fall back to fetching
the tips with their history. The relay makes the real daemon answer as such a server.
Loopback only; the thread of each connection ends when either side closes.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from types import TracebackType

from tests.gitserver import free_port


class OldProtocolRelay:
    """127.0.0.1:`port` → the daemon at 127.0.0.1:`target`, speaking protocol v0."""

    def __init__(self, target: int) -> None:
        self.target = target
        self.port = free_port()
        self.connections = 0
        self._server = socket.create_server(("127.0.0.1", self.port))
        self._server.settimeout(0.2)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def url(self, name: str) -> str:
        return f"git://127.0.0.1:{self.port}/{name}"

    def __enter__(self) -> OldProtocolRelay:
        self._threads.append(threading.Thread(target=self._accept, daemon=True))
        self._threads[0].start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)
        self._server.close()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._server.accept()
            except socket.timeout:
                continue
            self.connections += 1
            thread = threading.Thread(target=self._relay, args=(client,), daemon=True)
            self._threads.append(thread)
            thread.start()

    def _relay(self, client: socket.socket) -> None:
        """The request line rewritten, then bytes both ways until each side has closed:
        a side that finished sending (the client after its request) is half-closed, not
        the connection (no timeout either: a loaded machine may take long to answer)."""
        with client, socket.create_connection(("127.0.0.1", self.target), timeout=10) as up:
            up.settimeout(None)
            first = _pkt(client)
            up.sendall(_line(first.replace(b"\0version=2\0", b"\0")))

            def pipe(src: socket.socket, dst: socket.socket) -> None:
                with contextlib.suppress(OSError):
                    while True:
                        data = src.recv(65536)
                        if not data:
                            break
                        dst.sendall(data)
                with contextlib.suppress(OSError):
                    dst.shutdown(socket.SHUT_WR)

            back = threading.Thread(target=pipe, args=(up, client), daemon=True)
            back.start()
            pipe(client, up)
            back.join(timeout=60)


def _pkt(sock: socket.socket) -> bytes:
    """One pkt-line's payload (the request line of git://)."""
    size = int(_exactly(sock, 4), 16)
    return _exactly(sock, size - 4)


def _line(payload: bytes) -> bytes:
    return f"{len(payload) + 4:04x}".encode("ascii") + payload


def _exactly(sock: socket.socket, count: int) -> bytes:
    data = b""
    while len(data) < count:
        chunk = sock.recv(count - len(data))
        if not chunk:
            raise ConnectionError("the client closed the connection")
        data += chunk
    return data
