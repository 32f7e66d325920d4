"""State record 7 → 8: each change says who asked for it (`by`, schemas/record.py `Actor`).

Why: anyone in Bluetooth range of a parked car could change what it runs (issue 31), and
the record kept no trace of who did. Version 8 writes `by` on the history entries an
apply makes and on the last apply, `held_by` on an app an operator stopped, and `by` on a
rollback's hold. A version-7 record does not know who made its
changes, and the step does not guess: no `by` is added (it reads as "not recorded"), and
everything else is kept as written, so the step is the version alone.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """The version; `history` is checked to be a list of mappings, and kept as it is."""
    history = doc.get("history")
    if history is not None and not isinstance(history, list):
        raise MigrationError("`history` must be a list", loc=("history",))
    for index, entry in enumerate(history or []):
        if not isinstance(entry, dict):
            raise MigrationError("each `history` entry must be a mapping",
                                 loc=("history", index))
    return dict(doc, version=8)
