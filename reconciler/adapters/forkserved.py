"""Quiet hand-overs in the forkserver of `adapters.deadline`.

Place in the flow: imported only as a forkserver preload (`deadline._forkserver`), never
by lpam itself, so what it changes is the forkserver's process and the children it forks.

When lpam is interrupted or killed while it hands a request to the forkserver, the forked
child reads the request's half (or nothing) and multiprocessing prints an `EOFError`
traceback to the stderr it shares with lpam — under lpam's own "interrupted: …" line. lpam
has already said what happened and kills the child's group; nothing is lost, so the child
leaves quietly. Any other error still prints its traceback: that would be a bug to see.
"""

from __future__ import annotations

import sys
from types import TracebackType


def _quiet_eof(kind: type[BaseException], value: BaseException,
               traceback: TracebackType | None) -> None:
    if issubclass(kind, EOFError):
        return
    sys.__excepthook__(kind, value, traceback)


sys.excepthook = _quiet_eof
