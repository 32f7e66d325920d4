"""State record 4 → 5: several apps installed at once.

Why: version 4 kept one installed app (`app`), the one app a cutover returns to
(`cutover.previous`) and the one app a rollback found failing (`cutover.rollback.failed`).
A car that runs a controller beside a recorder and a tracker has a set of installed apps,
and an apply that fails returns to the set that ran before (issue 22). Version 5 keeps
each as a list, in the order the apps were installed: `apps`, `cutover.previous`,
`cutover.rollback.failed`. A version-4 record becomes the one-app list it described
(`app: null` → `apps: []`); nothing else changes.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError


def _listed(value: Any, loc: tuple[str, ...]) -> list[Any]:
    if value is None:
        return []
    if not isinstance(value, dict):
        raise MigrationError(f"`{'.'.join(loc)}` must be a mapping or null", loc=loc)
    return [value]


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """`app` → `apps`, and the cutover's one app → its list of apps."""
    out = {k: v for k, v in doc.items() if k != "app"}
    out["version"] = 5
    out["apps"] = _listed(doc.get("app"), ("app",))
    cutover = doc.get("cutover")
    if cutover is None:
        return out
    if not isinstance(cutover, dict):
        raise MigrationError("`cutover` must be a mapping or null", loc=("cutover",))
    cutover = dict(cutover, previous=_listed(cutover.get("previous"), ("cutover", "previous")))
    rollback = cutover.get("rollback")
    if rollback is not None:
        if not isinstance(rollback, dict):
            raise MigrationError("`cutover.rollback` must be a mapping or null",
                                 loc=("cutover", "rollback"))
        cutover["rollback"] = dict(rollback, failed=_listed(
            rollback.get("failed"), ("cutover", "rollback", "failed")))
    out["cutover"] = cutover
    return out
