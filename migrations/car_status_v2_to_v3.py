"""Car status 2 → 3: the file a car publishes gains `last_change`, and who asked for it.

Why: anyone in Bluetooth range of a parked car could change what it runs (issue 31); the
fleet must be able to see who put the app in place — a phone (its address and name), a
user at the car, or the agent with the fleet's revision. A version-2 file named no one:
`null`, nothing guessed.
"""

from __future__ import annotations

from typing import Any


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Add `last_change: null` and `version: 3`; nothing else changes."""
    return dict(doc, version=3, last_change=doc.get("last_change"))
