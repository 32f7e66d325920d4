"""One writer at a time: an advisory `flock` on `var/lib/lpam/apply.lock`.

flock is released by the kernel when the last holder of the open file closes it, so a
SIGKILLed or power-cut apply never leaves a stale lock behind. The descriptor is handed
on to the guard process around each app script (see adapters/scripts.py): if lpam dies
while `start.sh` runs, the lock stays held until that script has ended and its exit code
is written, so the next apply can neither run beside it nor run it a second time blind.

The file's content says who holds it and what runs ("pid 812: running alpha start.sh in
process group 815"), so a blocked apply can tell the user what to wait for — or what to
kill when the apply that started it is gone. The file is opened without following a
symbolic link: a link planted there would make lpam write through it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass

from reconciler.base.errors import LockError
from reconciler.base.flock import wait_exclusive
from reconciler.base.layout import Layout
from reconciler.base.text import printable

POLL_SECONDS = 0.1
NOTE_LIMIT = 512


@dataclass(frozen=True)
class Lock:
    """A held lock: `fd` is passed to script guards, `note` tells waiters what runs."""

    fd: int

    def note(self, text: str) -> None:
        data = f"pid {os.getpid()}: {text}\n".encode()[:NOTE_LIMIT]
        with contextlib.suppress(OSError):  # the note is a courtesy, never a failure
            os.ftruncate(self.fd, 0)
            os.pwrite(self.fd, data, 0)


def _open(layout: Layout) -> int:
    layout.lock.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(layout.lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC
                     | os.O_NONBLOCK, 0o644)
    except OSError as exc:
        kind = "a symbolic link" if exc.errno == errno.ELOOP else exc.strerror
        if exc.errno == errno.EISDIR:
            kind = "a directory"
        raise LockError(
            f"cannot open the lock file {layout.lock}: {kind}",
            hint=f"it must be a plain file that lpam creates; move it aside "
            f"(`mv {layout.lock} {layout.lock}.bad`) and run lpam again",
        ) from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise LockError(
            f"the lock file {layout.lock} is not a regular file",
            hint=f"move it aside (`mv {layout.lock} {layout.lock}.bad`) and run lpam again",
        )
    return fd


def _holder(fd: int) -> str:
    text = os.pread(fd, NOTE_LIMIT, 0).decode(errors="replace").strip()
    return printable(text)


@dataclass(frozen=True)
class Holding:
    """Who holds the lock, read from its note: the lpam process that took it (`pid`),
    whether that process still lives, and the process group of the app script it handed
    the lock to (None: none named). A holder whose lpam is gone is a script of an apply
    that has ended — never "an apply in progress"."""

    note: str
    pid: int | None
    alive: bool
    group: str | None

    @classmethod
    def of(cls, note: str) -> Holding:
        pid_text = note.removeprefix("pid ").split(":", 1)[0]
        pid = int(pid_text) if pid_text.isdigit() else None
        alive = True
        if pid is not None:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                alive = False
            except (PermissionError, OverflowError):
                pass
        group = None
        if "process group" in note:
            words = note.rsplit("process group", 1)[1].split()
            group = words[0] if words and words[0].isdigit() else None
        return cls(note, pid, alive, group)

    @property
    def orphaned(self) -> bool:
        """A script of an apply that has ended still runs, and holds the lock."""
        return not self.alive and self.group is not None

    def describe(self) -> str:
        """What holds the lock, said as every command says it (`apply` refused, `plan`
        beside it, `status`)."""
        what = self.note or "another lpam process"
        if self.orphaned:
            return (f"a script of an apply that has ended ({what}); the script is still "
                    "running")
        return f"an apply in progress ({what})"


def _busy_message(holder: str, layout: Layout) -> LockError:
    """What a blocked writer tells the user, from the holder's note."""
    holding = Holding.of(holder)
    if holding.orphaned:
        return LockError(
            f"lpam is locked by {holding.describe()}",
            hint="wait for it to finish — the next apply then resumes where it stood — or "
            f"stop it with `kill -- -{holding.group}` and apply again",
        )
    return LockError(
        f"another lpam apply holds {layout.lock} ({holder or 'another lpam process'})",
        hint="wait for it to finish, or pass --lock-timeout SECONDS to wait longer",
    )


@contextlib.contextmanager
def apply_lock(layout: Layout, *, timeout: float) -> Iterator[Lock]:
    """Hold the lock for the block, polling for at most `timeout` seconds to get it."""
    fd = _open(layout)
    try:
        if not wait_exclusive(fd, timeout=timeout, poll=POLL_SECONDS):
            raise _busy_message(_holder(fd), layout)
        lock = Lock(fd)
        lock.note("applying")
        yield lock
    finally:
        os.close(fd)


def holder(layout: Layout) -> str | None:
    """What holds the lock now (its note), or None when nobody does; creates nothing."""
    if not layout.lock.exists():
        return None
    try:
        fd = _open(layout)
    except LockError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _holder(fd) or "another lpam process"
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
