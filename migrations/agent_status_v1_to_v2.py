"""Agent status 1 → 2: the file a vehicle follows, its last publication, and `deferred`.

Why: a car published its status to `status/<vehicle>` after every pass, two connections
and one commit each time; version 2 records its last publication (`publication`: when,
what counted in it, whether the fleet repository took it) so that a pass publishes only a
changed status or a heartbeat (reconciler/core/publication.py), and the desired-state file it
follows (`follows`) so that `lpam fleet status` can show it. Version 1 also gained the
pass result `deferred` (a closed update gate) without a version step; version 2 is where
that result is named, and a version-1 file holding it (written by the lpam that added it)
is carried over as it is. A version-1 file never published under these rules (so its
next online pass publishes) and did not know which file it followed (the next pass that
reads the source fills it in).
"""

from __future__ import annotations

from typing import Any

from migrations.step import MigrationError


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Add `follows: null` and `publication: null`; everything else is kept."""
    for key in ("follows", "publication"):
        if doc.get(key) is not None:
            raise MigrationError(f"`{key}` is not part of an agent status version 1",
                                 loc=(key,), hint="move the file aside; the next pass "
                                 "writes a new one")
    return dict(doc, version=2, follows=None, publication=None)
