"""State record 6 → 7: the last apply is a closed state machine, `deferred` among its states.

Why: version 6 had no word for an apply the update gates deferred, so one ended as it
began, `in progress`, with a pid soon gone — and status then said lpam was killed or the
power failed, and told the user to resume a desired state that might no longer be the
one wanted. Version 7 writes `deferred` with the gates that were closed (and when the
agent tries again). Nothing a version-6 record says changes meaning: its last apply is
kept as written (an `in progress` still reads as live or cut off by its pid), and the new
fields are written only by a deferral, so the step is the version alone.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """The version; `last_apply` is checked to be a mapping, and kept as it is."""
    last = doc.get("last_apply")
    if last is not None and not isinstance(last, dict):
        raise MigrationError("`last_apply` must be a mapping or null", loc=("last_apply",))
    return dict(doc, version=7)
