"""Update locks held by apps around a critical section (balena's update lock is the model).

An app that records, calibrates or drives an experiment says "do not swap me now" with a
lock file, in one of two ways:
- an **flock** lock: the app runs `flock /run/lpam/locks/recording.lock -c 'record …'`
  (util-linux `flock` takes LOCK_EX). The kernel drops it when the holder dies, so it can
  never go stale. A missing file simply means "free".
- a **persistent** lock: a file whose mere existence means "held". Put on persistent storage
  it survives a reboot (an experiment spanning several drives); the app creates it and
  removes it, and until then lpam waits.

In the apply flow this is one of the update gates, checked just before the cutover: `take`
tries every lock; when one is busy the cutover is deferred and the holders are named
(`Busy.describe`). When none is, lpam *keeps* the flock locks until the cutover is over, so
that no app can begin a critical section mid-swap (its own `flock` blocks, or fails with
`-n`). The descriptors are close-on-exec: an app started during the cutover does not inherit
them and so cannot keep them held after lpam exits. `probe` takes and releases at once, for
`lpam gates`, which only reports.

Lock files are opened without following a symbolic link (a link planted at a lock path
would make lpam create or lock a file elsewhere), and are never removed by lpam: removing
an flock file while another process opens it lets two holders lock two different files.

Who holds an flock is read from `/proc/locks`; `parse_proc_locks` is its pure parser, with
fixtures in tests/contract/test_locks.py. Each line names the holder's pid and the locked
file's device (`MAJOR:MINOR`, in hex) and inode:

    1: FLOCK  ADVISORY  WRITE 4242 b3:02:131091 0 EOF
    1: -> FLOCK  ADVISORY  WRITE 4250 b3:02:131091 0 EOF      (a waiter, not a holder)

The pid is that of the process that took the lock (for `flock -c CMD`, the flock process
itself). The lock belongs to the open file, so if that process died while a child it started
keeps the descriptor, the line still names the dead pid (its command is then "?"), and a
holder in another pid namespace (a container) is not listed at all.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import stat
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from reconciler.base.errors import LpamError, shorten
from reconciler.base.text import printable

PROC = Path("/proc")
UNKNOWN_COMMAND = "?"
COMMAND_LIMIT = 120

LockSpec = tuple[Path, bool]  # (path, persistent)

_LOCK_LINE = re.compile(
    r"^\s*\d+:\s+(?P<waiter>->\s+)?(?P<kind>\S+)\s+(?P<mode>\S+)\s+(?P<access>\S+)\s+"
    r"(?P<pid>-?\d+)\s+(?P<major>[0-9a-fA-F]+):(?P<minor>[0-9a-fA-F]+):(?P<inode>\d+)\s")


@dataclass(frozen=True)
class Holder:
    """A process holding an flock: its pid and command line ("?" when it cannot be read)."""

    pid: int
    command: str


@dataclass(frozen=True)
class Busy:
    """A lock that keeps the cutover waiting."""

    path: Path
    holders: tuple[Holder, ...]
    persistent: bool

    def describe(self) -> str:
        """One line for the user: who holds the lock, or that the file exists."""
        if self.persistent:
            return f"{self.path} exists (a persistent lock; remove it to allow updates)"
        if not self.holders:
            return (f"{self.path} is held by a process lpam cannot see (not in /proc/locks, "
                    "perhaps in a container)")
        who = " and ".join(f"pid {h.pid} ({h.command})" for h in self.holders)
        return f"{self.path} is held by {who}"


@dataclass(frozen=True)
class LockLine:
    """One line of /proc/locks."""

    kind: str  # FLOCK, POSIX, OFDLCK, LEASE, DELEG
    access: str  # READ or WRITE
    pid: int
    major: int
    minor: int
    inode: int
    waiting: bool  # "->": blocked waiting for the lock, not holding it


def parse_proc_locks(text: str) -> list[LockLine]:
    """The lines of /proc/locks that name a file (lines with `<none>` do not)."""
    matches = (_LOCK_LINE.match(line + " ") for line in text.splitlines())
    return [LockLine(kind=match["kind"], access=match["access"], pid=int(match["pid"]),
                     major=int(match["major"], 16), minor=int(match["minor"], 16),
                     inode=int(match["inode"]), waiting=match["waiter"] is not None)
            for match in matches if match is not None]


def flock_holders(text: str, *, major: int, minor: int, inode: int) -> tuple[int, ...]:
    """The pids holding an flock on the file (device `major:minor`, `inode`), each once,
    from the text of /proc/locks. POSIX and OFD locks are left out: on Linux they do not
    conflict with flock, so they never keep lpam's lock from being taken."""
    return tuple(dict.fromkeys(
        line.pid for line in parse_proc_locks(text)
        if (line.kind == "FLOCK" and not line.waiting and line.inode == inode
            and line.major == major and line.minor == minor)))


def holders(path: Path, *, proc: Path = PROC) -> tuple[Holder, ...]:
    """Who holds an flock on `path` (empty when it is free, missing, or held by a process
    lpam cannot see)."""
    try:
        st = os.stat(path, follow_symlinks=False)
    except OSError:
        return ()
    return _holders(st, proc)


def _holders(st: os.stat_result, proc: Path) -> tuple[Holder, ...]:
    try:
        text = (proc / "locks").read_text(errors="replace")
    except OSError:
        return ()
    pids = flock_holders(text, major=os.major(st.st_dev), minor=os.minor(st.st_dev),
                         inode=st.st_ino)
    return tuple(Holder(pid, command_of(pid, proc=proc)) for pid in pids)


def command_of(pid: int, *, proc: Path = PROC) -> str:
    """The command line of process `pid`, or "?" when it is gone or cannot be read."""
    if pid <= 0:
        return UNKNOWN_COMMAND
    try:
        raw = (proc / str(pid) / "cmdline").read_bytes()
    except OSError:
        return UNKNOWN_COMMAND
    words = [w.decode(errors="replace") for w in raw.split(b"\0") if w]
    if not words:  # a zombie, or a kernel thread
        return UNKNOWN_COMMAND
    text = " ".join(words)
    return printable(shorten(text, COMMAND_LIMIT))


class UpdateLocks:
    """The update locks lpam holds across one cutover.

    `take` either takes every lock (and keeps the flock ones until `release`) or takes none
    and says which are busy. As a context manager it releases on exit, whatever happens.
    """

    def __init__(self, *, proc: Path = PROC) -> None:
        self._proc = proc
        self._held: list[tuple[Path, int]] = []

    @property
    def held(self) -> tuple[Path, ...]:
        """The flock files held now."""
        return tuple(path for path, _ in self._held)

    def take(self, specs: Sequence[LockSpec]) -> list[Busy]:
        """Try every lock of `specs` ((path, persistent) pairs). Empty when all were free:
        the flock ones are then held until `release`. Otherwise the busy ones, each with
        its holders, and nothing is held."""
        if self._held:
            raise RuntimeError("UpdateLocks.take called while holding locks; release first")
        busy: list[Busy] = []
        try:
            for path, persistent in dict.fromkeys(specs):  # a lock named twice is one lock
                found = _persistent(path) if persistent else self._flock(path)
                if found is not None:
                    busy.append(found)
        except BaseException:
            self.release()
            raise
        if busy:
            self.release()
        return busy

    def release(self) -> None:
        """Let go of every lock held; closing the descriptor is what releases an flock."""
        held, self._held = self._held, []
        for _, fd in held:
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> UpdateLocks:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.release()

    def _flock(self, path: Path) -> Busy | None:
        fd = _open(path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            found = Busy(path, _holders(os.fstat(fd), self._proc), persistent=False)
            os.close(fd)
            return found
        except BaseException:
            os.close(fd)
            raise
        self._held.append((path, fd))
        return None


def probe(specs: Sequence[LockSpec], *, proc: Path = PROC) -> list[Busy]:
    """The busy locks of `specs` now, holding none afterwards (for `lpam gates`)."""
    with UpdateLocks(proc=proc) as locks:
        return locks.take(specs)


def _persistent(path: Path) -> Busy | None:
    try:
        st = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:  # a missing folder too: the app never took the lock
        return None
    except OSError as exc:
        raise _unusable(path, exc) from None
    if stat.S_ISLNK(st.st_mode):
        raise _refused(path, "a symbolic link")
    if stat.S_ISDIR(st.st_mode):
        raise _refused(path, "a directory")
    return Busy(path, (), persistent=True)


def _open(path: Path) -> int:
    """A read-only descriptor on the flock file, created (mode 0644, parents too) when
    missing: apps that are not root can still open it to flock it. O_NONBLOCK keeps a FIFO
    planted at the path from hanging lpam."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC
                     | os.O_NONBLOCK, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _refused(path, "a symbolic link") from None
        if exc.errno == errno.EISDIR:
            raise _refused(path, "a directory") from None
        raise _unusable(path, exc) from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise _refused(path, "a special file")
    return fd


def _refused(path: Path, what: str) -> LpamError:
    return LpamError(
        f"update lock {path} is {what}, not a plain file",
        hint="lpam never follows a link or locks a directory there; move it aside "
        f"(`mv {path} {path}.bad`) or fix the lock's path in the desired state")


def _unusable(path: Path, exc: OSError) -> LpamError:
    return LpamError(
        f"cannot use the update lock {path}: {exc.strerror or exc}",
        hint=f"lpam must be able to create and open it: check {path.parent} and its "
        "permissions (lpam runs as root on the vehicle), or fix the lock's path")
