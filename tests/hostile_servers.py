"""Servers that never let a client finish: a black hole and a slow drip, on 127.0.0.1.

They stand in for the WiFi at the edge of a car park: a connection that opens and then
nothing comes (the black hole), or a byte now and then, forever (the drip), which no
per-read socket timeout ever trips. Both run in threads of the test process, stop by
themselves when the `with` block ends, and wait for nothing longer than a fraction of a
second, so a test can never hang on them.
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable, Iterator
from types import TracebackType

# What a drip sends first: for git://, the length of a pkt-line far longer than the test
# (0xfff0 bytes at two a second); for http://, a status line and a header that never ends.
GIT_DRIP = b"fff0"
HTTP_DRIP = b"HTTP/1.1 200 OK\r\nContent-Type: application/x-git-upload-pack-advertisement\r\nX-"


class HostileServer:
    """Accepts TCP connections on loopback and then never completes an answer.

    With `drip=None` nothing is ever sent (a black hole); otherwise `drip` is sent one
    byte every `interval` seconds, followed by 'a's, until the client goes away.
    """

    def __init__(self, *, drip: bytes | None = None, interval: float = 0.5) -> None:
        self.drip = drip
        self.interval = interval
        self.connections = 0
        self._stop = threading.Event()
        self._listener = socket.socket()
        self._threads: list[threading.Thread] = []
        self._sockets: list[socket.socket] = []

    @property
    def port(self) -> int:
        return int(self._listener.getsockname()[1])

    def url(self, scheme: str, path: str = "lab/apps.git", *, userinfo: str = "") -> str:
        auth = f"{userinfo}@" if userinfo else ""
        return f"{scheme}://{auth}127.0.0.1:{self.port}/{path}"

    def __enter__(self) -> HostileServer:
        self._listener.bind(("127.0.0.1", 0))
        self._listener.listen(16)
        self._listener.settimeout(0.1)
        self._start(self._accept)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)
        for sock in [self._listener, *self._sockets]:
            sock.close()

    def _start(self, target: Callable[..., None], *args: object) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except (socket.timeout, TimeoutError):  # one class since 3.10; not on 3.9
                continue
            except OSError:
                return
            self.connections += 1
            self._sockets.append(conn)
            if self.drip is not None:
                self._start(self._send_slowly, conn)

    def _send_slowly(self, conn: socket.socket) -> None:
        for byte in _endless(self.drip or b""):
            if self._stop.wait(self.interval):
                return
            try:
                conn.sendall(byte)
            except OSError:  # the client gave up
                return


def _endless(first: bytes) -> Iterator[bytes]:
    for i in range(len(first)):
        yield first[i : i + 1]
    while True:
        yield b"a"
