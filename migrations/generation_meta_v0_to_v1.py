"""Generation metadata 0 → 1: the file beside each generation gets a version, and its app
is `name`, as in every other shape of a generation.

Why: the metadata file (`generations/<app>/<id>.json`) was hand-written JSON with no
version, so a later lpam could not tell what an older one wrote. Version 1 is the same
content with `version: 1`, its app named `name` (schemas/generation.py GenerationMeta
shares its fields with a plan's step and the state record's app). A file with no
`version` is version 0 (reconciler/engine/records/generations.py says so before upgrading); it is
carried over as it is, every other key kept.
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Rename `app` to `name` and add `version: 1`."""
    if "name" in doc:
        raise MigrationError("`name` is not part of generation metadata version 0",
                             loc=("name",), hint="move the file aside; lpam falls back on "
                             "the state record")
    out = {key: value for key, value in doc.items() if key != "app"}
    if "app" in doc:
        out["name"] = doc["app"]
    return dict(out, version=1)
