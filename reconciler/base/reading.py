"""Reading files lpam does not control, without being led astray by them.

Every file lpam reads — a desired state, a saved plan, its own state record and journal,
LPAM's files, an app folder — may be damaged, huge, a FIFO that never answers, a device
such as /dev/zero, or a symbolic link planted to make lpam print `/etc/shadow`. So every
read goes through `read_bounded`: the file is opened without blocking, must be a regular
file, is read up to a limit and no further, and (for lpam's own files) is never reached
through a final symbolic link. Failures are `ConfigError`s naming the file and what to do,
never a hang, an exhausted memory or a traceback.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from reconciler.base.errors import ConfigError

KIB = 1024
MIB = 1024 * KIB


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _size(limit: int) -> str:
    return f"{limit // MIB} MiB" if limit >= MIB and limit % MIB == 0 else f"{limit // KIB} KiB"


def read_bounded(
    path: Path, *, limit: int, follow_symlinks: bool = True, what: str = "file",
    hint: str | None = None,
) -> bytes:
    """The bytes of the regular file `path`, at most `limit` of them.

    `follow_symlinks=False` is for lpam's own files (state record, journal, plans it
    wrote): a link there was not made by lpam and is refused rather than followed.
    Raises FileNotFoundError when the file does not exist (callers decide whether that
    is an error), ConfigError for everything else that makes the file unusable.
    """
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
    if not follow_symlinks:
        flags |= os.O_NOFOLLOW
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise
    except OSError as exc:
        if exc.errno == errno.ELOOP and not follow_symlinks:
            raise ConfigError(
                f"{what} is a symbolic link; lpam does not follow links to its own files",
                path=path, hint=hint or "remove the link; lpam writes a real file there",
            ) from None
        if exc.errno == errno.ENAMETOOLONG:
            raise ConfigError(f"{what}: the path is too long", path=path) from None
        raise ConfigError(f"cannot read {what}: {exc.strerror}", path=path, hint=hint) from None
    too_large = f"{what} is larger than {_size(limit)}; is it the right file?"
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise ConfigError(
                f"{what} is {_kind(info.st_mode)}, not a regular file", path=path,
                hint=hint or "point lpam at a regular file",
            )
        if info.st_size > limit:
            raise ConfigError(too_large, path=path, hint=hint)
        chunks: list[bytes] = []
        remaining = limit + 1  # one byte more than allowed tells a file that grew meanwhile
        while remaining > 0:
            chunk = os.read(fd, min(remaining, 64 * KIB))
            if not chunk:
                break
            chunks.append(chunk)
            remaining -= len(chunk)
        data = b"".join(chunks)
    except OSError as exc:
        raise ConfigError(f"cannot read {what}: {exc.strerror}", path=path, hint=hint) from None
    finally:
        os.close(fd)
    if len(data) > limit:
        raise ConfigError(too_large, path=path, hint=hint)
    return data


def open_append(path: Path, *, mode: int = 0o644) -> int:
    """An O_APPEND descriptor for one of lpam's own logs, never through a symbolic link
    (a planted `debug.log -> /etc/passwd` must not be written through)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK
    try:
        fd = os.open(path, flags, mode)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ConfigError(
                "is a symbolic link; lpam does not write through links to its own files",
                path=path, hint="remove the link; lpam creates a real file there",
            ) from None
        raise ConfigError(f"cannot write: {exc.strerror}", path=path) from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ConfigError("is not a regular file; lpam cannot log there", path=path,
                          hint="remove it; lpam creates a real file there")
    return fd


TAIL_LIMIT = MIB  # bytes read back from a log's end for its last lines


def tail(path: Path, lines: int, *, since: int = 0) -> list[str]:
    """The last `lines` lines of a log (an app's unit's, or the apply log from byte `since`
    on: one script's output), read backwards from its end, at most TAIL_LIMIT bytes, without
    their line ends: what an error shows of a failed app, whoever ran it. A missing file, or
    one that is not a regular file, has no lines."""
    fd = None if lines <= 0 else open_regular(path)
    if fd is None:
        return []
    try:
        end = os.fstat(fd).st_size
        data = b""
        start = end
        floor = max(min(since, end), 0)
        while start > floor and data.count(b"\n") <= lines and end - start < TAIL_LIMIT:
            step = min(64 * KIB, start - floor, TAIL_LIMIT - (end - start))
            start -= step
            data = os.pread(fd, step, start) + data
    finally:
        os.close(fd)
    parts = data.decode(errors="replace").split("\n")
    if parts and parts[-1] == "":
        parts.pop()
    if start > floor and parts:
        parts.pop(0)  # begun mid-line
    return [p.removesuffix("\r") for p in parts[-lines:]]


def open_regular(path: Path) -> int | None:
    """A read descriptor for a log, None unless it is a regular file (a FIFO, a device):
    a log is a courtesy, never a hang."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | os.O_NOCTTY)
    except OSError:
        return None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        return None
    return fd
