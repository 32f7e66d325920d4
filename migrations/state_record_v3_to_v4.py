"""State record 3 → 4: an app is good only once it proved good; a cutover survives faults.

Why: version 3 could not tell an app that passed its health check from one whose check a
kill cut off, nor remember which app a failed apply must return to once lpam had died:
the next run trusted the unproven app and forgot the failure. Version 4 adds `app.good`
and `cutover` (reconciler/engine/execution/recovery.py), and what status must not guess: the
desired state of the last apply (`desired`, what holds hold against) and each
repository's commit as of the last successful apply (`applied`). A version-3 app was
installed by the old rules, which took it for good, so it stays good; its checkouts are
taken as applied; no cutover is under way; which desired state it came from is unknown.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Mark the installed app good, its checkouts applied; no cutover, no desired known."""
    out = dict(doc, version=4)
    app = out.get("app")
    if app is not None:
        if not isinstance(app, dict):
            raise MigrationError("`app` must be a mapping or null", loc=("app",))
        out["app"] = {**app, "good": app.get("good", True)}
    repositories = out.get("repositories")
    if repositories is not None:
        if not isinstance(repositories, list):
            raise MigrationError("`repositories` must be a list", loc=("repositories",))
        out["repositories"] = [{**r, "applied": r.get("commit")} if isinstance(r, dict)
                               else r for r in repositories]
    out.setdefault("cutover", None)
    out.setdefault("desired", None)
    return out
