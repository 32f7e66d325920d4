"""The processes a dead supervisord left running, found and ended.

systemd keeps a unit's processes in a cgroup that outlives any crash; supervisord only
has pids, and when it is killed (`kill -9`, the OOM killer) its programs live on,
re-parented, unsupervised and invisible to it — a second start would put a second copy of
the app on the CAN bus. So every program lpam writes for supervisord carries two marks in
its environment, which its children inherit: `LPAM_SUPERVISOR` (the configuration of the
supervisord that runs it: one per lpam root) and `LPAM_UNIT` (the program). Whatever
carries the marks of this root once its supervisord is gone — or that supervisord does
not run as that program — is an orphan: reported as running but unsupervised, and ended
(its process group, then the process itself: TERM, then KILL after the unit's stop time)
before anything of the unit is started again.

Reading `/proc/<pid>/environ` needs the process's user or root: the user that runs
lpam, and so its supervisord, can read every app it runs.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from pathlib import Path

SUPERVISOR_MARK = "LPAM_SUPERVISOR"
UNIT_MARK = "LPAM_UNIT"
ENVIRON_LIMIT = 256 * 1024  # an environment larger than this is not one lpam gave
POLL = 0.05
PROC = Path("/proc")


def marks(conf: Path, unit: str) -> dict[str, str]:
    """The environment that marks `unit` as run by the supervisord of `conf`."""
    return {SUPERVISOR_MARK: str(conf), UNIT_MARK: unit}


def _environ(pid: int) -> dict[bytes, bytes] | None:
    try:
        fd = os.open(PROC / str(pid) / "environ", os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        data = os.read(fd, ENVIRON_LIMIT)
    except OSError:
        return None
    finally:
        os.close(fd)
    pairs = (item.partition(b"=") for item in data.split(b"\0") if item)
    return {key: value for key, _, value in pairs}


def _zombie(pid: int) -> bool:
    try:
        stat = (PROC / str(pid) / "stat").read_text()
    except OSError:
        return True  # gone
    return stat.rsplit(")", 1)[-1].split()[:1] in (["Z"], ["X"])


def find(conf: Path, unit: str | None = None, *, besides: frozenset[int] = frozenset()
         ) -> list[int]:
    """The live processes marked as run by the supervisord of `conf` (as `unit`, when
    given), except `besides` (what that supervisord runs now) and lpam itself."""
    mark = os.fsencode(str(conf))
    wanted = None if unit is None else os.fsencode(unit)
    mine = {os.getpid(), os.getppid()}
    found = []
    try:
        entries = list(os.scandir(PROC))
    except OSError:
        return []
    for entry in entries:
        if not entry.name.isdigit():
            continue
        pid = int(entry.name)
        if pid in mine or pid in besides:
            continue
        env = _environ(pid)
        if env is None or env.get(SUPERVISOR_MARK.encode()) != mark:
            continue
        if wanted is not None and env.get(UNIT_MARK.encode()) != wanted:
            continue
        if not _zombie(pid):
            found.append(pid)
    return sorted(found)


def _signal(pids: list[int], sig: signal.Signals) -> None:
    own = os.getpgrp()
    for pid in pids:
        with contextlib.suppress(OSError):
            group = os.getpgid(pid)
            if group not in (0, 1, own):
                os.killpg(group, sig)  # the app's children are in its group (stopasgroup)
        with contextlib.suppress(OSError):
            os.kill(pid, sig)


def end(pids: list[int], *, wait: float) -> list[int]:
    """TERM each process and its group, KILL what is left after `wait` seconds; the pids
    that are still there after that (none, unless the kernel keeps one in D state)."""
    if not pids:
        return []
    _signal(pids, signal.SIGTERM)
    left = _wait(pids, wait)
    if left:
        _signal(left, signal.SIGKILL)
        left = _wait(left, 5.0)
    return left


def _wait(pids: list[int], seconds: float) -> list[int]:
    deadline = time.monotonic() + seconds
    while True:
        left = [pid for pid in pids if not _zombie(pid)]
        if not left or time.monotonic() >= deadline:
            return left
        time.sleep(POLL)
