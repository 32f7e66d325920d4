"""What the tests of a car that runs at most one app ask of its state record, and a row of
the status report as LPAM's table shows it."""

from __future__ import annotations

from schemas.record import AppRecord, StateRecord
from schemas.report import CatalogRow


def sole(record: StateRecord) -> AppRecord:
    """The installed app of a car that runs one (these tests' cars do, and this says so:
    none, or a second installed app, fails the test)."""
    assert len(record.apps) == 1, f"not one app installed: {[a.name for a in record.apps]}"
    return record.apps[0]


def lpam_row(repository: str, branch: str, app: str, service: str, enabled: bool,
             running: bool, description: str) -> CatalogRow:
    """A row of LPAM's app table (`-d`, the phone's `A`) as the status report holds it."""
    return CatalogRow(repository=repository, ref=branch, commit="c" * 12, app=app,
                      service=service or "-", installed=enabled, running=running,
                      status="running" if enabled else None, description=description)
