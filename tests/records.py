"""What the tests of a car that runs at most one app ask of its state record."""

from __future__ import annotations

from schemas.record import AppRecord, StateRecord


def sole(record: StateRecord) -> AppRecord:
    """The installed app of a car that runs one (these tests' cars do, and this says so:
    none, or a second installed app, fails the test)."""
    assert len(record.apps) == 1, f"not one app installed: {[a.name for a in record.apps]}"
    return record.apps[0]
