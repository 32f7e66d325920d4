"""Desired state 1 → 2: the one app under `app:` becomes a list under `apps:`.

Why: issue 22 lets several apps run side by side (a controller that owns the panda beside
a recorder and a tracker), and version 1 could name only one. The step is pure and total
on what version 1 allowed:

- `app: {name: x, …}` → `apps: [{name: x, …}]`, the entry untouched;
- `app: x` (the shorthand) → `apps: [x]`: version 2 takes the name alone in a list too;
- `app: null`, or no `app:` at all → `apps: []`.

Every other key is carried as it is. The entry is not checked here: the schema checks it
after the step, and documents.py maps a fault at `apps.0.…` back to `app.…` of the file
the user wrote, so a version-1 file's faults keep their line and column.

The reverse never happens in lpam's reading, but lpam's *edits* of a version-1 file keep
it version 1 on disk (workflow/editing.py edits the file's own tree): the Bluetooth
service and `libpanda-app-manager` must not rewrite a fleet's file in a newer dialect.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError

KEYS = ("app",)
"""Top-level keys of version 1 that version 2 no longer has (validation.py's guess)."""


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Return the version-2 equivalent of a version-1 desired state; `doc` is untouched."""
    if "apps" in doc:
        raise MigrationError(
            "unknown key 'apps' in a version 1 desired state", loc=("apps",),
            hint="version 1 names one app under `app:`; write `version: 2` to list apps "
            "under `apps:`",
        )
    out = {key: value for key, value in doc.items() if key != "app"}
    app = doc.get("app")
    out["version"] = 2
    out["apps"] = [] if app is None else [app]
    return out
