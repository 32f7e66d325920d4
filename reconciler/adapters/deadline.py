"""A network operation in a child process that is gone, with everything it started, when its
deadline passes.

Place in the flow: `adapters.remote.Transport` runs each network operation through `run`,
so that `--network-timeout` bounds the operation's total time whatever the transport does
inside (see `adapters.wire`).

Children are forked by a multiprocessing *forkserver*: one helper process per lpam process,
started at the first network operation, that has already imported dulwich's network stack
(`adapters.wire`). Forking from it costs milliseconds, where starting a fresh interpreter
and importing dulwich.client cost ~0.1 s of CPU per operation — measured in
docs/benchmarks.md, that made a plan of 20 branches 5x slower. The forkserver is
single-threaded, so forking it is safe even while lpam resolves repositories from a thread
pool (forking lpam itself would not be). It exits when lpam does.

Each child leads its own session and process group (an ssh it starts is in it). That whole
group is ended — SIGTERM, a short grace so dulwich deletes its half-written pack, then
SIGKILL — on the deadline, on Ctrl-C or on any other exception here; when the child has
answered, anything it left in its group is killed too. A child whose pipe to lpam reaches
end of file has lost lpam (killed) and kills its own group (`wire.serve`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from multiprocessing.connection import Connection
    from multiprocessing.context import ForkServerContext
    from multiprocessing.process import BaseProcess

# Imported inside functions: multiprocessing loads only when the forkserver is first needed, or
# in warm()'s thread to overlap lpam's imports (start-up); wire and json are cheap by then.

_GRACE = 1.0  # seconds between SIGTERM and SIGKILL: time for the child to delete temp files
_POLL = 0.2  # how often a wait checks that the child is still alive
_lock = threading.Lock()
_context: ForkServerContext | None = None


class Expired(Exception):
    """The deadline passed; the child and its process group have been killed."""


def _forkserver() -> ForkServerContext:
    global _context
    with _lock:
        if _context is None:
            import multiprocessing

            context = multiprocessing.get_context("forkserver")
            context.set_forkserver_preload(
                ["reconciler.adapters.forkserved", "reconciler.adapters.wire", "dulwich.client"])
            _context = context
        return _context


def warm() -> None:
    """Start the forkserver now, in the background, for a caller that will soon need the
    network: its ~0.1 s of start-up (a fresh interpreter importing dulwich's client) then
    overlaps lpam's own imports instead of delaying the first fetch. Harmless if unused:
    the forkserver exits with lpam."""

    def start() -> None:
        from multiprocessing import forkserver

        _forkserver()
        with contextlib.suppress(OSError):  # the first fetch then starts it, or reports why
            forkserver.ensure_running()

    threading.Thread(target=start, name="lpam-forkserver", daemon=True).start()


def run(request: dict[str, str], *, timeout: float) -> dict[str, Any] | None:
    """The child's answer to `request` (None if it died without one); `Expired` when it has
    not answered within `timeout` seconds."""
    from reconciler.adapters import wire

    deadline = time.monotonic() + timeout
    context = _forkserver()
    mine, theirs = context.Pipe(duplex=True)
    proc = context.Process(target=wire.serve, args=(theirs, request, dict(os.environ)),
                           name="lpam-network", daemon=False)
    try:
        proc.start()
        theirs.close()  # only the child holds its end: its death is end of file here
        answer = _answer(mine, proc, deadline)
    except BaseException:
        _end(proc)
        raise
    finally:
        mine.close()
    _signal_group(proc, signal.SIGKILL)  # leftovers only: the child has answered
    proc.join(timeout=5)
    return answer


def _answer(conn: Connection, proc: BaseProcess, deadline: float) -> dict[str, Any] | None:
    import json

    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise Expired
        if conn.poll(min(remaining, _POLL)):
            try:
                answer = json.loads(conn.recv_bytes())
            except (EOFError, OSError, ValueError):  # it died without answering, or garbled
                return None
            return answer if isinstance(answer, dict) else None
        if not proc.is_alive() and not conn.poll(0):
            return None


def _signal_group(proc: BaseProcess, signum: int) -> None:
    """Signal the child's group — which exists only once the child made it (setsid); a
    child killed before that is signalled directly."""
    pid = proc.pid
    if pid is None:
        return
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pid, signum)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.kill(pid, signum)


def _end(proc: BaseProcess) -> None:
    """SIGTERM the child's group, give it a moment to clean up, then SIGKILL what is left."""
    if proc.pid is None:
        return
    _signal_group(proc, signal.SIGTERM)
    proc.join(timeout=_GRACE)
    _signal_group(proc, signal.SIGKILL)
    proc.join(timeout=5)  # SIGKILL cannot be ignored; only a hung kernel call delays it
