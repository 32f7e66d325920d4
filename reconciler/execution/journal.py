"""The apply journal (`var/lib/lpam/journal.jsonl`): one JSON line per event, fsynced.

Each step is journalled before its work ("begin") and after it ("end" or "fail"), as
Mender persists its state before each state's work. The journal holds the last apply
only. After a power cut or SIGKILL, a step with "begin" and no end is the interrupted one:
the next apply reports it and runs it again, while steps that ended are not repeated
(they are already reflected in the state record). A torn last line is ignored.
"""

from __future__ import annotations

import json
import os
from datetime import datetime

from reconciler.atomic import append_durable, write_atomic
from reconciler.layout import Layout

VERSION = 1


class Journal:
    def __init__(self, layout: Layout, *, apply_id: str, plan: str) -> None:
        self._path = layout.journal
        self._apply = apply_id
        self._plan = plan

    def open(self, now: datetime) -> None:
        """Start a fresh journal for this apply (the previous one was read already)."""
        write_atomic(self._path, "")
        self._write("apply-begin", None, now)

    def begin(self, step: str, now: datetime) -> None:
        self._write("begin", step, now)

    def end(self, step: str, now: datetime) -> None:
        self._write("end", step, now)

    def fail(self, step: str, now: datetime, message: str) -> None:
        self._write("fail", step, now, message=message)

    def close(self, now: datetime) -> None:
        self._write("apply-end", None, now)

    def _write(self, event: str, step: str | None, now: datetime, **extra: str) -> None:
        line = {"v": VERSION, "apply": self._apply, "plan": self._plan, "pid": os.getpid(),
                "event": event, "step": step, "at": now.isoformat(timespec="seconds"), **extra}
        append_durable(self._path, json.dumps(line, sort_keys=True))


def read_events(layout: Layout) -> list[dict[str, object]]:
    try:
        text = layout.journal.read_text(encoding="utf-8")
    except FileNotFoundError:
        return []
    events = []
    for raw in text.splitlines():
        try:
            event = json.loads(raw)
        except json.JSONDecodeError:
            continue  # a line torn by a power cut
        if isinstance(event, dict):
            events.append(event)
    return events


def interrupted_steps(layout: Layout) -> list[str]:
    """Steps the last apply began and never finished (empty if it ended, or failed cleanly)."""
    events = read_events(layout)
    if not events or any(e.get("event") == "apply-end" for e in events):
        return []
    open_steps: dict[str, None] = {}
    for event in events:
        step = event.get("step")
        if not isinstance(step, str):
            continue
        if event.get("event") == "begin":
            open_steps[step] = None
        else:
            open_steps.pop(step, None)
    return list(open_steps)

