"""Run a long external command (apt-get, pip, catkin_make) the way every adapter must.

Its output is streamed line by line to a `Log` (the apply log and the terminal's progress
line), from the calling thread, and the last lines are kept for the error message; it runs
in its own process group, which is killed whole when the command passes its deadline —
even while it prints nothing — or lpam is interrupted, so no compiler or installer outlives
the apply that started it.
"""

from __future__ import annotations

import queue
import shlex
import subprocess
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from reconciler.adapters.scripts import stop_group
from reconciler.base.errors import DETAIL_LINES
from reconciler.engine.execution.ports import Log


@dataclass
class Outcome:
    """How a command ended: its exit code (None when it was killed at its deadline, 127
    when it could not be started) and its last lines of output."""

    code: int | None
    tail: list[str] = field(default_factory=list)


def run_streamed(
    argv: list[str], *, log: Log, deadline: float, env: Mapping[str, str] | None = None,
    cwd: Path | None = None,
) -> Outcome:
    """Run `argv` (an argument list, never a shell string) with stdin closed, until
    `deadline` (time.monotonic)."""
    log(f"$ {shlex.join(argv)}")
    try:
        proc = subprocess.Popen(
            argv, cwd=cwd, env=None if env is None else dict(env), stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    except OSError as exc:
        return Outcome(127, [f"cannot run {argv[0]}: {exc.strerror}"])
    lines: queue.Queue[bytes | None] = queue.Queue()
    threading.Thread(target=_pump, args=(proc, lines), daemon=True).start()
    tail: list[str] = []
    try:
        while (raw := lines.get(timeout=_left(deadline))) is not None:
            line = raw.decode(errors="replace").rstrip("\r\n")
            log(line)
            tail = [*tail[1 - DETAIL_LINES:], line]
        return Outcome(proc.wait(timeout=_left(deadline)), tail)
    except (queue.Empty, subprocess.TimeoutExpired):
        stop_group(proc)
        return Outcome(None, [*tail, f"killed: {argv[0]} did not finish in the time allowed"])
    except BaseException:  # Ctrl-C, SIGTERM: the command must not outlive lpam
        stop_group(proc)
        raise


def _left(deadline: float) -> float:
    return max(deadline - time.monotonic(), 0.001)


def _pump(proc: subprocess.Popen[bytes], lines: queue.Queue[bytes | None]) -> None:
    """Move the output to the caller's thread, which alone calls `log` and keeps time."""
    assert proc.stdout is not None
    with proc.stdout:
        for raw in proc.stdout:
            lines.put(raw)
    lines.put(None)
