"""What the three frontends — `lpam`, `libpanda-app-manager` and `lpam ble` — share as
callers of the workflow: how events are shown in a terminal, where the traceback of a bug
goes (never to the user), and SIGTERM raised where lpam stands.

Below the frontends and above the workflow (`.importlinter`): written once, so that the
shim does not reach into the CLI's private names and the Bluetooth service logs a bug the
way the CLI does.
"""

from __future__ import annotations

import os
import sys
import traceback
from datetime import datetime, timezone

from reconciler import __version__
from reconciler.base.errors import LpamError, Terminated
from reconciler.base.layout import Layout
from reconciler.base.text import printable
from reconciler.workflow.events import Event


def now() -> datetime:
    return datetime.now(timezone.utc)


def terminate(signum: int, frame: object) -> None:
    """SIGTERM as an exception raised where lpam stands (reconciler/base/errors.py)."""
    raise Terminated


def debug_log(layout: Layout) -> str:
    """Append the traceback to lpam's debug log, never through a planted link."""
    from reconciler.base.reading import open_append

    try:
        fd = open_append(layout.debug_log)
    except (OSError, LpamError):
        return "(the debug log could not be written)"
    try:
        text = f"--- {now().isoformat()} lpam {__version__} {sys.argv}\n" + traceback.format_exc()
        os.write(fd, text.encode("utf-8", "replace"))
    except OSError:
        return "(the debug log could not be written)"
    finally:
        os.close(fd)
    return str(layout.debug_log)


class Terminal:
    """Where the use cases' events go in a terminal: notes to stderr, progress to stdout,
    and of a long command's output (a build, an install) its command line, then at most
    every few seconds how long it has run and its latest line."""

    EVERY = 5.0

    def __init__(self) -> None:
        import time

        self._clock = time.monotonic
        self._started = self._shown = self._clock()

    def __call__(self, event: Event) -> None:
        from reconciler.core.planning.render import render
        from reconciler.workflow.events import Note, Output, Planned, Progress

        if isinstance(event, Note):
            print(f"note: {event.text}", file=sys.stderr)
        elif isinstance(event, Progress):
            print(event.text, flush=True)
        elif isinstance(event, Planned):
            print(render(event.plan))
        elif isinstance(event, Output):
            self._output(event.line)

    def _output(self, line: str) -> None:
        now_ = self._clock()
        if line.startswith("$ "):  # a new command: its clock starts
            self._started = self._shown = now_
            print(f"      {fit(line, 100)}", flush=True)
        elif now_ - self._shown >= self.EVERY:
            self._shown = now_
            print(f"      … {now_ - self._started:.0f} s: {fit(line, 80)}", flush=True)


def fit(line: str, width: int) -> str:
    """`line` in at most `width` printable characters, cut in the middle: the end of a
    command line (the path, the package) is the part that says most."""
    text = printable(line)
    if len(text) <= width:
        return text
    head = width * 2 // 5
    return f"{text[:head]} … {text[len(text) - (width - head - 3):]}"
