"""Waiting for an flock with a bound: the apply lock and supervisord's launch lock both
poll a non-blocking `flock` rather than block, so that a stuck holder costs a clear error
after a known time instead of a hang (the kernel releases the lock if its holder dies)."""

from __future__ import annotations

import fcntl
import time

POLL_SECONDS = 0.05


def wait_exclusive(fd: int, *, timeout: float, poll: float = POLL_SECONDS) -> bool:
    """Take the exclusive lock on `fd`; False when `timeout` seconds passed without it."""
    deadline = time.monotonic() + max(timeout, 0.0)
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(poll)
