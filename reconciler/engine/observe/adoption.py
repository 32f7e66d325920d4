"""Whether the app LPAM installed is already the desired app, so that lpam adopts it as it
runs instead of stopping, reinstalling and restarting it (a recording interrupted for
nothing). Read-only, like every probe.

It is, when the folder LPAM copied to `/etc/libpanda.d/apps/<folder>` holds exactly the
files of the desired app's folder at the desired commit — compared by content (git blob
ids, which name content only: LPAM's copy may differ in modes) — and lpam would run it the
way LPAM did: by its scripts, with no parameters, no user and no dependencies lpam would
prepare (LPAM prepared them its own way). Anything else is taken over as before: stopped
and uninstalled with its own scripts, then installed anew.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.blobs import blob_id
from reconciler.base.layout import Layout

if TYPE_CHECKING:
    from reconciler.core.planning.model import Targets
    from reconciler.engine.execution.ports import Store
    from schemas.record import StateRecord

FILES_LIMIT = 10_000
BYTES_LIMIT = 256 * 1024 * 1024  # read at most this much of LPAM's folder to compare it


def adoptable(layout: Layout, store: Store, record: StateRecord,
              targets: Targets) -> dict[str, str]:
    """Each desired app that an app LPAM installed (a stray) is, as it is: desired app →
    stray. Only an app lpam would run as LPAM did (scripts, no parameters, no dependencies
    to prepare) and that is not installed under its name is taken over; each stray once."""
    found: dict[str, str] = {}
    for app in targets.apps:
        if record.installed(app.name) is not None or app.commit is None or app.path is None:
            continue
        if app.command is not None or app.launch is not None or app.params or app.user or \
                app.deps.how:
            continue
        for stray in record.strays:
            if stray.folder is None or stray.folder != app.folder or \
                    stray.pending is not None or stray.name in found.values():
                continue
            wanted = store.folder_blobs(app.repository, app.commit, app.path)
            if wanted is not None and wanted == disk_blobs(layout.libpanda_apps / stray.folder):
                found[app.name] = stray.name
                break
    return found


def disk_blobs(folder: Path) -> dict[str, str] | None:
    """Each file below `folder` (links not followed) and the git blob id of its content;
    None when the folder cannot be read whole or is too large to be an app's."""
    found: dict[str, str] = {}
    budget = BYTES_LIMIT
    try:
        for top, dirs, files in os.walk(folder, followlinks=False):
            for name in files + [d for d in dirs if os.path.islink(os.path.join(top, d))]:
                path = os.path.join(top, name)
                relative = os.path.relpath(path, folder).replace(os.sep, "/")
                info = os.lstat(path)
                if stat.S_ISLNK(info.st_mode):
                    data = os.fsencode(os.readlink(path))
                elif stat.S_ISREG(info.st_mode) and info.st_size <= budget:
                    with open(path, "rb") as handle:
                        data = handle.read(budget + 1)
                else:
                    return None  # a device, a FIFO, or too much to be an app folder
                budget -= len(data)
                if budget < 0 or len(found) >= FILES_LIMIT:
                    return None
                found[relative] = blob_id(data)
    except OSError:
        return None
    return found
