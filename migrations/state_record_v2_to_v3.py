"""State record 2 → 3: apps become supervised services, with a history and a last result.

Why: version 2 knew only scripts and what they reported. Version 3 records how the app runs
(`service`: the unit whose live state says whether it runs; `command`/`launch`/`user` for
a scriptless app whose unit lpam writes), whether an operator's `lpam stop` holds it
(`held`), how the last apply ended (`last_apply`), the generations made current
(`history`, for `lpam history` and `lpam rollback`) and a rollback that holds (`hold`).
Strays gain the unit lpam wrote for them and, for an app LPAM installed, its folder.
A version-2 record knew none of these, so each starts empty: no unit (the state stays
what the scripts reported), not held, no history.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError

_APP_FIELDS = {"service": None, "command": None, "launch": None, "user": None, "held": False}


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Add the version-3 fields with their empty values."""
    out = dict(doc, version=3)
    app = out.get("app")
    if app is not None:
        if not isinstance(app, dict):
            raise MigrationError("`app` must be a mapping or null", loc=("app",))
        out["app"] = {**_APP_FIELDS, **app}
    strays = out.get("strays", [])
    if not isinstance(strays, list):
        raise MigrationError("`strays` must be a list", loc=("strays",))
    out["strays"] = [{"service": None, "folder": None, **s} if isinstance(s, dict) else s
                     for s in strays]
    out.setdefault("last_apply", None)
    out.setdefault("history", [])
    out.setdefault("hold", None)
    return out
