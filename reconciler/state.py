"""Read and write the state record (`var/lib/lpam/state.json`, format in schemas/record.py).

Every write is atomic and bumps the serial; the first write fixes the lineage. A record
written by a newer lpam is refused by name instead of being misread.
"""

from __future__ import annotations

import json
import uuid
from pathlib import Path

from reconciler.atomic import write_atomic
from reconciler.layout import Layout
from schemas.record import StateRecord


def read_record(layout: Layout) -> StateRecord:
    """The last recorded state, or an empty record on a machine lpam never touched."""
    path = layout.state_record
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return StateRecord()
    return parse_record(text, path)


def parse_record(text: str, path: Path) -> StateRecord:
    from reconciler.documents import parse_json

    return parse_json("state-record", text, path, StateRecord,
                      hint="restore it from a backup, or remove it to start afresh")


def write_record(layout: Layout, record: StateRecord) -> StateRecord:
    """Persist `record` as the next serial; returns what was written."""
    lineage = record.lineage or str(uuid.uuid4())
    written = record.model_copy(update={"lineage": lineage, "serial": record.serial + 1})
    text = json.dumps(written.model_dump(mode="json"), indent=2, sort_keys=True) + "\n"
    write_atomic(layout.state_record, text)
    return written
