"""One apply at a time: an advisory `flock` on `var/lib/lpam/apply.lock`.

flock is released by the kernel when the holder dies, so a SIGKILLed or power-cut apply
never leaves a stale lock behind. A second apply polls for at most `timeout` seconds.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from collections.abc import Iterator

from reconciler.errors import LockError
from reconciler.layout import Layout

POLL_SECONDS = 0.1


@contextlib.contextmanager
def apply_lock(layout: Layout, *, timeout: float) -> Iterator[None]:
    layout.lock.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(layout.lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        deadline = time.monotonic() + max(timeout, 0.0)
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                    raise LockError(
                        f"another lpam apply (pid {holder}) holds {layout.lock}",
                        hint="wait for it to finish, or pass --lock-timeout SECONDS to wait longer",
                    ) from None
                time.sleep(POLL_SECONDS)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)
