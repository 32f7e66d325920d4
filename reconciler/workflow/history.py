"""The history use case (`lpam history`): the generations made current, newest last, and
which of them is the one installed now."""

from __future__ import annotations

from dataclasses import dataclass

from reconciler.layout import Layout
from schemas.record import HistoryEntry


@dataclass(frozen=True)
class Made:
    """One generation made current; `current`: it is the installed app, as applied."""

    entry: HistoryEntry
    current: bool


def history(layout: Layout) -> list[Made]:
    """Every generation the record remembers making current, oldest first."""
    from reconciler.state import read_record

    record = read_record(layout)
    app = record.app
    return [Made(h, app is not None and h.result == "applied"
                 and (h.generation, h.params) == (app.generation, app.params))
            for h in record.history]
