"""Which of lpam's files another user may change, and how to close each (issue 31 item 4):
decided from modes and owners alone. reconciler/report/gather.py stats the paths `watched`
names (one `os.stat` each); reconciler/report/build.py turns what it found into the
report's `exposed` list, which the table and `--json` show.

Whoever may write the desired state, the state record, the store, an app's folder or
lpam's logs can make root run their code (reconciler/base/modes.py says why each counts),
so a path is exposed when:
- its group or others may write it. For one of lpam's own directories that holds even
  with the sticky bit (another user could still add an entry lpam reads, an override or a
  journal); a directory *above* lpam's files with the sticky bit (as /tmp is) is safe, as
  only an entry's owner may rename or remove it there;
- it belongs to a user other than root and the user lpam runs as: its owner may chmod it
  at will. Root owns everything already.
Every directory from the root down to each path is checked too: whoever may write a
parent can move lpam's directory aside and put their own in its place.

Cheap by design: a few dozen known paths, never a walk. The store, the generations, the
apps' Python environments and LPAM's app folders are checked at their top directories,
with each recorded repository's checkout and each installed app's generation: a walk of
every checkout and generation on each status would read thousands of entries, slow on a
Pi. What lpam makes inside them is unwritable by others from the start (base/modes.py); a
mode someone changes deep inside one later is not seen here. Links are followed (a
desired state linked to a file in a user's home is that user's to change); the parents
of a link's target are not checked.
"""

from __future__ import annotations

import shlex
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.layout import is_generation_id
from schemas.report import ExposedPath, Writer

if TYPE_CHECKING:
    from reconciler.base.layout import Layout
    from schemas.record import StateRecord

ABOVE = "a directory above lpam's files"


@dataclass(frozen=True)
class Watched:
    """A path checked, and what lpam keeps there (None: a directory above lpam's files)."""

    path: Path
    what: str | None


@dataclass(frozen=True)
class Found:
    """A watched path as it stands: its mode and owner."""

    path: Path
    what: str | None
    mode: int
    uid: int
    gid: int


@dataclass(frozen=True)
class Files:
    """What gather read: the watched paths that exist, the user lpam runs as, and the
    names of the users and groups they belong to (None: no name known)."""

    found: tuple[Found, ...]
    user: int
    users: Mapping[int, str | None]
    groups: Mapping[int, str | None]


def watched(layout: Layout, record: StateRecord) -> list[Watched]:
    """Every path checked, each once, each directory above before what is in it."""
    own = [
        (layout.etc, "lpam's configuration"),
        (layout.desired_state, "the desired state"),
        (layout.agent_config, "the agent's settings"),
        (layout.supervisor_dir, "supervisord's configuration"),
        (layout.supervisor_programs, "the programs supervisord runs"),
        (layout.var, "lpam's state"),
        (layout.state_record, "the state record"),
        (layout.journal, "the journal of an apply"),
        (layout.override, "the local override"),
        (layout.runs, "the exit codes of the apps' scripts"),
        (layout.repositories, "the repository store"),
        *[(layout.repository_dir(r.key), f"the checkout of {r.key}")
          for r in record.repositories],
        (layout.generations, "the apps' generations"),
        *[(layout.generation_dir(a.name, a.generation), f"the generation {a.name} runs from")
          for a in record.apps if is_generation_id(a.generation)],
        (layout.venvs, "the apps' Python environments"),
        (layout.libpanda_apps, "LPAM's app folders"),
        (layout.logs, "lpam's logs"),
        (layout.app_logs, "the apps' logs"),
        (layout.debug_log, "lpam's debug log"),
        (layout.run_dir, "lpam's runtime files (supervisord's socket, locks)"),
    ]
    named = dict(own)
    seen: dict[Path, str | None] = {}
    for path, what in own:
        for above in reversed(path.relative_to(layout.root).parents):
            seen.setdefault(layout.root / above, named.get(layout.root / above))
        seen.setdefault(path, what)
    return [Watched(path, what) for path, what in seen.items()]


def exposed(files: Files) -> list[ExposedPath]:
    """Each path another user may change, with what to do, in the order watched."""
    name = files.users.get(files.user)
    me, chown = (name, name) if name else (f"uid {files.user}", str(files.user))
    found = []
    for item in files.found:
        writers = _writers(item)
        owner = None if item.uid in (0, files.user) else \
            f"{files.users.get(item.uid) or 'an unknown user'} (uid {item.uid})"
        if not writers and owner is None:
            continue
        path = shlex.quote(str(item.path))
        fix = " && ".join([*([f"chown {chown} {path}"] if owner is not None else []),
                           *([f"chmod go-w {path}"] if writers else [])])
        group = files.groups.get(item.gid) or f"gid {item.gid}"
        problems = (["world-writable"] if "others" in writers else
                    [f"writable by its group ({group})"] if writers else [])
        problems += [] if owner is None else [f"owned by {owner}"]
        what = item.what or ABOVE
        found.append(ExposedPath(
            path=str(item.path), what=what, writable_by=writers, owner=owner, fix=fix,
            said=f"{item.path} ({what}) is {' and '.join(problems)}: another user can "
            f"change what lpam runs as {me}; `{fix}` closes it"))
    return found


def _writers(item: Found) -> list[Writer]:
    """Who besides the owner may write it: its group, others, neither or both."""
    if item.what is None and stat.S_ISDIR(item.mode) and item.mode & stat.S_ISVTX:
        return []  # a sticky directory above: only an entry's owner may move it
    found: list[Writer] = []
    if item.mode & stat.S_IWGRP:
        found.append("group")
    if item.mode & stat.S_IWOTH:
        found.append("others")
    return found
