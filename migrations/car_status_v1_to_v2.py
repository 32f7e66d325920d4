"""Car status 1 → 2: the file a car publishes gains `override`.

Why: a car that follows a fleet repository can be steered on the spot — a phone over
Bluetooth, `libpanda-app-manager` — and then runs something other than its fleet file
says, on purpose (schemas/override.py). The fleet must see that, or `lpam fleet status`
would show the car as simply out of date. A version-1 file had no override: `null`.
"""

from __future__ import annotations

from typing import Any


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Add `override: null` and `version: 2`; nothing else changes."""
    return dict(doc, version=2, override=doc.get("override"))
