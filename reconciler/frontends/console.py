"""What the three frontends — `lpam`, `libpanda-app-manager` and `lpam ble` — share as
callers of the workflow: how events are shown in a terminal, the guard that turns what ends
a request badly into the face's one line (a bug's traceback goes to the debug log, never to
the user), and SIGTERM raised where lpam stands.

Below the frontends and above the workflow (`.importlinter`): written once, so that the
shim does not reach into the CLI's private names and the Bluetooth service logs a bug the
way the CLI does.
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import signal
import sys
import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from reconciler import __version__
from reconciler.base.errors import LpamError, Terminated
from reconciler.base.layout import Layout
from reconciler.base.text import printable
from reconciler.workflow.machine import now

if TYPE_CHECKING:
    from reconciler.workflow.events import Event

# Imported inside functions: the plan renderer (pydantic) loads only when a plan is printed
# (start-up); the others (events, reading, time) are cheap and follow that use.

T = TypeVar("T")

EXIT_BUG, EXIT_INTERRUPTED, EXIT_TERMINATED = 1, 130, 143  # 128 + SIGINT, 128 + SIGTERM

REDELIVER_SECONDS = 0.01


def terminate(signum: int, frame: object) -> None:
    """SIGTERM as an exception raised where lpam stands (reconciler/base/errors.py)."""
    raise Terminated


def raise_signals_where_lpam_stands() -> None:
    """SIGTERM raises `Terminated` and Ctrl-C `KeyboardInterrupt` wherever lpam stands — and
    one that lands where Python cannot raise is delivered again instead of lost.

    Python runs a signal's handler between any two bytecodes, also inside a weakref
    callback or a `__del__` (the import system's module locks have one): an exception
    raised there is printed as "Exception ignored in …" with its traceback, and the command
    goes on as if it had not been asked to stop. `_redelivered` catches that case, prints
    nothing, and raises the same interrupt again moments later, where lpam stands.
    """
    signal.signal(signal.SIGTERM, terminate)
    sys.unraisablehook = _redelivered


def _redelivered(unraisable: Any) -> None:
    """sys.unraisablehook: an interrupt that could not be raised is raised again
    REDELIVER_SECONDS later (by SIGALRM, which lpam uses for nothing else), by then out of
    the callback it fell in; anything else is printed as Python prints it."""
    lost = unraisable.exc_type
    if (not issubclass(lost, (Terminated, KeyboardInterrupt))
            or threading.current_thread() is not threading.main_thread()):
        sys.__unraisablehook__(unraisable)
        return

    def again(signum: int, frame: object) -> None:
        raise lost()

    signal.signal(signal.SIGALRM, again)
    signal.setitimer(signal.ITIMER_REAL, REDELIVER_SECONDS)


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


def guarded(
    body: Callable[[], T], *, bug: Callable[[], str], internal: Callable[[Exception, str], T],
    failed: Callable[[LpamError], T] | None = None,
    interrupted: Callable[[BaseException], T] | None = None,
    closed: Callable[[], T] | None = None,
) -> T:
    """`body()`, or the face's answer to what ended it: no traceback reaches a user.

    A bug — an exception the face names no answer for — has its traceback written by
    `bug` (to the debug log: `debug_log`), and `internal(exc, where)` answers, pointing
    there. A command names the rest (`exit_code`): `failed`, a user's error; `interrupted`,
    Ctrl-C or SIGTERM (`Terminated`); `closed`, its stdout closed by the reader. The
    Bluetooth service names none: the phone's answers name each request's failure, so an
    LpamError that reaches its guard is a bug, and its loop stops on its own signals.
    """
    try:
        return body()
    except LpamError as exc:
        return internal(exc, bug()) if failed is None else failed(exc)
    except BrokenPipeError as exc:
        return internal(exc, bug()) if closed is None else closed()
    except (KeyboardInterrupt, Terminated) as exc:
        if interrupted is None:
            raise
        return interrupted(exc)
    except Exception as exc:  # a bug: keep the traceback away from the user, but keep it
        return internal(exc, bug())


def exit_code(
    body: Callable[[], int], *, bug: Callable[[], str], failed: Callable[[LpamError], str],
    interrupted: Callable[[], str], internal: Callable[[str], str],
) -> int:
    """A command's guard (`lpam`, `libpanda-app-manager`): `body`'s exit code, or one line
    on stderr and the code of what ended it — a user's error its own (`LpamError.exit_code`),
    an interrupt 130 (Ctrl-C) or 143 (SIGTERM), a bug 1 with `internal(where)` pointing at
    its traceback. A stdout closed by its reader (`lpam plan | head`) ends quietly with 0."""

    def said(line: str, code: int) -> int:
        print(line, file=sys.stderr)
        return code

    return guarded(
        body, bug=bug,
        failed=lambda exc: said(failed(exc), exc.exit_code),
        interrupted=lambda exc: said(interrupted(), EXIT_TERMINATED
                                     if isinstance(exc, Terminated) else EXIT_INTERRUPTED),
        closed=_closed,
        internal=lambda exc, where: said(internal(where), EXIT_BUG),
    )


def _closed() -> int:
    """The reader of stdout left: nothing more to say, and nothing more said (Python's
    flush of stdout at exit would fail again)."""
    with contextlib.suppress(OSError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


SUGGESTED = re.compile(r"(?<!by )`lpam(?=[ `])(?! --)")
"""A command lpam suggests, as every layer writes one: in backquotes, from `lpam`. One
that begins with an option (a resume command: cli.again) is spelled in full already; one
after "by" names what an earlier command did ("held by `lpam rollback`"), to run no more."""


@dataclass(frozen=True)
class Calling:
    """How a command lpam suggests must call lpam to act where this one acted. The layers
    below write a suggestion as `lpam apply`: this lpam, on this car. On a car (root /)
    that is what the user types; on another root, copied as printed it would act on / —
    so the face spells each one with the root, absolute (it is run from any directory),
    and the service manager named on the command line. Texts are spelled where they are
    printed, so that every face derives its commands from one value."""

    options: tuple[str, ...] = ()

    @classmethod
    def of(cls, root: Path, *, services: str | None = None) -> Calling:
        words = [] if root == Path("/") else ["--root", str(root)]
        if services is not None:
            words += ["--services", services]
        return cls(tuple(words))

    @property
    def words(self) -> list[str]:
        """`lpam` and the options every suggested command repeats."""
        return ["lpam", *self.options]

    def spell(self, text: str) -> str:
        """`text` with each command it suggests spelled as the user must type it here."""
        if not self.options:
            return text
        spelled = "`" + shlex.join(self.words)
        return SUGGESTED.sub(lambda found: spelled, text)

    def spell_values(self, value: Any) -> Any:
        """A JSON value with every text in it spelled (`status --json` says the same
        sentences as the table: a reader that shows one must be able to run it)."""
        if isinstance(value, str):
            return self.spell(value)
        if isinstance(value, dict):
            return {key: self.spell_values(item) for key, item in value.items()}
        if isinstance(value, list):
            return [self.spell_values(item) for item in value]
        return value


class Terminal:
    """Where the use cases' events go in a terminal: notes to stderr, progress to stdout,
    and of a long command's output (a build, an install) its command line, whole (a user
    may copy it to run it again), then at most every few seconds how long it has run and
    its latest line. Every command a text suggests is spelled by `calling`."""

    EVERY = 5.0

    def __init__(self, calling: Calling | None = None) -> None:
        import time

        self._clock = time.monotonic
        self._started = self._shown = self._clock()
        self._spell = (calling or Calling()).spell

    def __call__(self, event: Event) -> None:
        from reconciler.core.planning.render import render
        from reconciler.workflow.events import Fetched, Note, Output, Planned, Progress

        if isinstance(event, (Note, Fetched)):
            print(self._spell(f"note: {event.text}"), file=sys.stderr)
        elif isinstance(event, Progress):
            print(self._spell(event.text), flush=True)
        elif isinstance(event, Planned):
            print(self._spell(render(event.plan)))
        elif isinstance(event, Output):
            self._output(event.line)

    def _output(self, line: str) -> None:
        now_ = self._clock()
        if line.startswith("$ "):  # a new command: its clock starts
            self._started = self._shown = now_
            print(f"      {printable(line)}", flush=True)
        elif now_ - self._shown >= self.EVERY:
            self._shown = now_
            print(f"      … {now_ - self._started:.0f} s: {fit(line, 80)}", flush=True)


def fit(line: str, width: int) -> str:
    """`line` in at most `width` printable characters, cut at its end with "…": what is
    shown reads as it was printed (a cut in the middle joined two halves of a command
    into one that does not exist)."""
    text = printable(line)
    if len(text) <= width:
        return text
    return f"{text[:width - 1]}…"
