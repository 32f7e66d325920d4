"""The apply journal (`var/lib/lpam/journal.jsonl`): one JSON line per event, fsynced.

Each step is journalled before its work ("begin") and after it ("end" or "fail"), as
Mender persists its state before each state's work. The journal holds the last apply
only. After a power cut or SIGKILL, a step with "begin" and no end is the interrupted one:
the next apply reports it and runs it again, while steps that ended are not repeated
(they are already reflected in the state record). A torn last line is ignored. An apply
whose cutover a closed update gate deferred ends with a "deferred" event (its reasons)
before "apply-end"; what `lpam status` says of it comes from the state record's last apply
(`deferred`), which any later apply ends — one with nothing to do included.

The journal is advisory — the state record is what lpam trusts — so a damaged one never
blocks anything: a reader skips what it cannot parse (bad UTF-8, JSON nested too deep, a
file too large, a directory or link in its place), and a writer moves whatever is not a
regular file aside to `journal.jsonl.damaged-<time>` and starts afresh, saying so. Each
line is appended through `reading.open_append`, which never follows a link and never
waits on a FIFO, so a link planted mid-apply is refused (a ConfigError naming the file)
instead of being written through.

The engine writes it (`Journal`) and the probes read it (`interrupted_steps`, `deferral`):
it sits below both, beside the state record, whose file it accompanies.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.base.reading import MIB, open_append, read_bounded

VERSION = 1
LIMIT = 4 * MIB  # one apply's events are a few KiB; more is not a journal lpam wrote
STEP_LIMIT = 300


class Journal:
    def __init__(self, layout: Layout, *, apply_id: str, plan: str) -> None:
        self._path = layout.journal
        self._apply = apply_id
        self._plan = plan

    def open(self, now: datetime, *, warn: Callable[[str], None] = lambda _: None) -> None:
        """Start a fresh journal for this apply (the previous one was read already)."""
        moved = _move_aside(self._path, now)
        if moved is not None:
            warn(f"note: {self._path} was not a regular file; moved it to {moved} and "
                 "started a new journal")
        try:
            write_atomic(self._path, "")
        except OSError as exc:  # whatever stands there could not be moved aside either
            raise ConfigError(
                f"cannot start the apply journal: {exc.strerror}", path=self._path,
                hint="move it elsewhere or delete it; lpam writes a new journal there",
            ) from None
        self._write("apply-begin", None, now)

    def begin(self, step: str, now: datetime) -> None:
        self._write("begin", step, now)

    def end(self, step: str, now: datetime) -> None:
        self._write("end", step, now)

    def fail(self, step: str, now: datetime, message: str) -> None:
        self._write("fail", step, now, message=message)

    def defer(self, now: datetime, reason: str) -> None:
        """The cutover was due but a gate stayed closed; `close` follows."""
        self._write("deferred", None, now, message=reason)

    def close(self, now: datetime) -> None:
        self._write("apply-end", None, now)

    def _write(self, event: str, step: str | None, now: datetime, **extra: str) -> None:
        line = {"v": VERSION, "apply": self._apply, "plan": self._plan, "pid": os.getpid(),
                "event": event, "step": step, "at": now.isoformat(timespec="seconds"), **extra}
        fd = open_append(self._path)
        try:
            os.write(fd, (json.dumps(line, sort_keys=True) + "\n").encode("utf-8"))
            os.fsync(fd)  # journalled before the step's work: it must survive a power cut
        finally:
            os.close(fd)


def _move_aside(path: Path, now: datetime) -> Path | None:
    """Move a directory, link or other non-file at `path` out of the way; where it went.

    It is kept, not deleted: a directory there may hold something a person put there."""
    try:
        if not (path.is_symlink() or (path.exists() and not path.is_file())):
            return None
        stem = f"{path.name}.damaged-{now.strftime('%Y%m%dT%H%M%S')}"
        names = [stem, *(f"{stem}.{n}" for n in range(1, 100))]  # several within a second
        aside = next((path.with_name(n) for n in names
                      if not os.path.lexists(path.with_name(n))), None)
        if aside is None:
            return None
        os.rename(path, aside)  # never over an existing name: it would replace an empty dir
        return aside
    except OSError:
        return None  # write_atomic then reports what stands in the way


def read_events(layout: Layout) -> list[dict[str, object]]:
    """The journal's events; what cannot be read is skipped, never an error."""
    try:
        data = read_bounded(layout.journal, limit=LIMIT, follow_symlinks=False, what="journal")
    except (FileNotFoundError, ConfigError):
        return []
    events = []
    for raw in data.decode("utf-8", "replace").splitlines():
        try:
            event = json.loads(raw)
        except (json.JSONDecodeError, RecursionError):
            continue  # a line torn by a power cut, or not lpam's
        if isinstance(event, dict):
            events.append(event)
    return events


def deferral(layout: Layout) -> tuple[str, str] | None:
    """(when, why) if the last apply ended deferred by a closed gate."""
    for event in reversed(read_events(layout)):
        if event.get("event") == "deferred":
            at, why = event.get("at"), event.get("message")
            if isinstance(at, str) and isinstance(why, str):
                return at[:40], why[:2000]
            return None
    return None


def interrupted_steps(layout: Layout) -> list[str]:
    """Steps the last apply began and never finished (empty if it ended, or failed cleanly)."""
    events = read_events(layout)
    if not events or any(e.get("event") == "apply-end" for e in events):
        return []
    open_steps: dict[str, None] = {}
    for event in events:
        step = event.get("step")
        if not isinstance(step, str) or len(step) > STEP_LIMIT or not step.isprintable():
            continue  # not a step id lpam wrote: never echo it
        if event.get("event") == "begin":
            open_steps[step] = None
        else:
            open_steps.pop(step, None)
    return list(open_steps)

