"""A child process that is gone, with everything it started, when its deadline passes.

Place in the flow: `adapters.remote.Transport` runs each network operation through `run`,
so that `--network-timeout` bounds the operation's total time whatever the transport does
inside (see `adapters.wire`). The child leads a new process group, and that whole group is
ended — SIGTERM, a short grace, then SIGKILL — on the deadline, on Ctrl-C or on any other
exception in the parent; when the child finishes normally, anything it left running in its
group (an ssh it started) is killed too. The group is always signalled before the child is
reaped, while its zombie still holds the group id, so the signal cannot reach a stranger
that was given a recycled id.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import signal
import subprocess
import time
from dataclasses import dataclass

_GRACE = 1.0  # seconds between SIGTERM and SIGKILL: time for the child to delete temp files
_STDERR_KEPT = 64 * 1024  # the tail of stderr that is kept for an error message


class Expired(Exception):
    """The deadline passed; the child and its process group have been killed."""


@dataclass(frozen=True)
class Finished:
    returncode: int
    stdout: bytes
    stderr: bytes


def run(argv: list[str], request: bytes, *, timeout: float) -> Finished:
    """Run `argv` with `request` on its stdin, which stays open until the child ends (the
    child may take end of file as the sign that its parent died); raise `Expired` when it
    has not finished within `timeout` seconds."""
    deadline = time.monotonic() + timeout
    proc = subprocess.Popen(
        argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        assert proc.stdin is not None
        with contextlib.suppress(BrokenPipeError):  # a child that died at once: see stderr
            proc.stdin.write(request)
            proc.stdin.flush()
        stdout, stderr = _collect(proc, deadline)
        while not _exited(proc.pid):  # it closed its output; its exit is a moment away
            if time.monotonic() >= deadline:
                raise Expired
            time.sleep(0.005)
    except BaseException:
        _end_group(proc)
        raise
    _signal_group(proc.pid, signal.SIGKILL)  # leftovers only: the child itself has exited
    returncode = proc.wait()
    _close(proc)
    return Finished(returncode, stdout, stderr)


def _collect(proc: subprocess.Popen[bytes], deadline: float) -> tuple[bytes, bytes]:
    """All of stdout and the tail of stderr, read until the child has closed stdout and
    exited (a grandchild may hold stderr open longer) or the deadline passes."""
    stdout, stderr = proc.stdout, proc.stderr
    assert stdout is not None and stderr is not None
    out: list[bytes] = []
    err = b""
    with selectors.DefaultSelector() as selector:
        selector.register(stdout, selectors.EVENT_READ)
        selector.register(stderr, selectors.EVENT_READ)
        while selector.get_map():
            answered = stdout.closed
            if answered and _exited(proc.pid):
                break
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise Expired
            for key, _ in selector.select(min(remaining, 0.05) if answered else remaining):
                pipe = stdout if key.fileobj is stdout else stderr
                chunk = os.read(pipe.fileno(), 65536)
                if not chunk:
                    selector.unregister(pipe)
                    pipe.close()
                elif pipe is stdout:
                    out.append(chunk)
                else:
                    err = (err + chunk)[-_STDERR_KEPT:]
    return b"".join(out), err


def _exited(pid: int) -> bool:
    """Whether the child has exited, without reaping it (its zombie keeps the group id)."""
    return os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None


def _signal_group(pgid: int, signum: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, signum)


def _end_group(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM the child's group, give it a moment to clean up, then SIGKILL what is left."""
    _signal_group(proc.pid, signal.SIGTERM)
    grace_ends = time.monotonic() + _GRACE
    while not _exited(proc.pid) and time.monotonic() < grace_ends:
        time.sleep(0.01)
    _signal_group(proc.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=5)  # SIGKILL cannot be ignored; only a hung kernel call delays it
    _close(proc)


def _close(proc: subprocess.Popen[bytes]) -> None:
    for pipe in (proc.stdin, proc.stdout, proc.stderr):
        if pipe is not None:
            with contextlib.suppress(OSError):
                pipe.close()
