"""State record 1 → 2: the app's `running` flag becomes a lifecycle `status`.

Why: version 1 wrote only what a finished script left (`running: true|false`), so a
record written while `start.sh` was cut off by a kill said "installed, not running" for an
app whose service was in fact up — and the next apply installed a second app beside it.
Version 2 writes the status *before* each script (`starting`, `stopping`, …) with the
run's id, and lists `strays`: generations found installed on disk that no record knew.
A version-1 record was only ever written between scripts, so its flag maps exactly:
`running: true` → `status: running`, otherwise `status: installed`; it had no strays.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Map `app.running` to `app.status`; add an empty `strays` list."""
    out = dict(doc, version=2)
    app = out.get("app")
    if app is not None:
        if not isinstance(app, dict):
            raise MigrationError("`app` must be a mapping or null", loc=("app",))
        app = dict(app)
        running = app.pop("running", False)
        if not isinstance(running, bool):
            raise MigrationError("`app.running` must be true or false", loc=("app", "running"))
        app["status"] = "running" if running else "installed"
        out["app"] = app
    out.setdefault("strays", [])
    return out
