"""The history use case (`lpam history`): the sets of apps made current, newest last, and
which of them is the one installed now (a car of one app makes sets of one)."""

from __future__ import annotations

from dataclasses import dataclass

from reconciler.base.layout import Layout
from reconciler.core.planning.holds import same_set
from reconciler.engine.records.state import read_record
from schemas.record import HistoryEntry, history_sets


@dataclass(frozen=True)
class Made:
    """One generation made current (or rolled back); `current`: it is installed now, as
    applied; `set`: the number of the apply's set it belongs to (entries of one apply
    share it)."""

    entry: HistoryEntry
    current: bool
    set: int = 0


def history(layout: Layout) -> list[Made]:
    """Every generation the record remembers making current, oldest first."""
    record = read_record(layout)
    made = []
    for number, entries in enumerate(history_sets(record.history)):
        current = entries[0].result == "applied" and same_set(entries, record.apps)
        made += [Made(h, current, number) for h in entries]
    return made
