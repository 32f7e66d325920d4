"""State record 5 → 6: one model of apps, so a hold names its set and nothing else.

Why: version 5 kept two views of what a rollback returns to — `hold.target` (one app, the
world before several apps) beside `hold.targets` (several) — and `hold.generation`, a name
derived from them. Version 6 keeps `hold.targets` alone: one app is a set of one. The
fingerprint a hold holds against (`hold.desired`) is kept as it is, so a hold recorded by
version 5 still holds after the upgrade, until the desired state changes.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """`hold.target` → `hold.targets` (a set of one); `hold.generation` dropped."""
    out = dict(doc, version=6)
    hold = doc.get("hold")
    if hold is None:
        return out
    if not isinstance(hold, dict):
        raise MigrationError("`hold` must be a mapping or null", loc=("hold",))
    targets = hold.get("targets") or []
    if not isinstance(targets, list):
        raise MigrationError("`hold.targets` must be a list", loc=("hold", "targets"))
    target = hold.get("target")
    if not targets and target is not None:
        targets = [target]
    out["hold"] = {**{k: v for k, v in hold.items() if k not in ("target", "generation")},
                   "targets": targets}
    return out
