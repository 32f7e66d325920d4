"""`lpam pin`: what was tested is what the cars run.

Every repository of a desired-state file that follows a branch or a tag (or the default
branch) is pinned to the full commit it points at now, the name it followed kept as a
comment on the line; everything else in the file — comments, key order, quoting, blank
lines — stays as it was (ruamel.yaml's round trip). With `catalogs`, the ROS repositories
of the app the file names are reported as they resolve now (they are pinned in the app's
catalog, which is the app repository's to change, not this file's).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base import roundtrip
from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ConfigError
from reconciler.base.loading import load, read_text
from reconciler.core.documents import desired_from
from reconciler.engine.execution.lock import apply_lock
from reconciler.engine.observe.targets import Fetch, resolve
from reconciler.engine.records.legacy.appdir import libpanda_user
from reconciler.workflow.defaults import FETCH_LOCK_TIMEOUT
from reconciler.workflow.events import Progress, Report
from reconciler.workflow.machine import Machine
from schemas.names import is_hex_commit

if TYPE_CHECKING:
    from schemas.desired import DesiredState


@dataclass(frozen=True)
class Pinned:
    """One repository pinned: its key, what it followed, the commit it is pinned to."""

    key: str
    was: str
    commit: str


def pin(machine: Machine, path: Path, *, report: Report, catalogs: bool = False,
        write: bool = True, lock_timeout: float | None = None) -> list[Pinned]:
    """Pin `path` in place (unless not `write`); the repositories pinned."""
    text = read_text(path)
    # refuse a bad file before anything is asked of a remote; the tree validated is the one
    # rewritten (quotes kept), so the text is read and composed once
    doc = load(path, text, keep_quotes=True)
    desired = desired_from(doc)
    store = machine.store()
    yaml = roundtrip.writer(text)  # the file's own style, no line re-wrapped
    data = doc.tree
    if data.get("version") not in (1, 2):  # the file keeps its version: only refs change
        raise ConfigError("lpam pin rewrites version 1 and 2 desired states only", path=path,
                          hint="upgrade the file first (lpam validate says how)")
    items = data.get("repositories") or []
    if len(items) != len(desired.repositories):
        raise ConfigError("the file changed while lpam pinned it", path=path,
                          hint="run lpam pin again")
    done: list[Pinned] = []
    for spec, item in zip(desired.repositories, items):
        if spec.ref is not None and is_hex_commit(spec.ref) and len(spec.ref) == 40:
            continue
        url = desired.mirrored(spec.source(path.resolve().parent))
        commit = store.ls_remote(url).resolve(spec.ref)
        if commit is None:
            raise ConfigError(f"repository {spec.key}: {spec.ref or 'the default branch'} "
                              f"does not exist in {url}", path=path,
                              hint="fix `ref:` first; the file was not changed")
        was = spec.ref or "default branch"
        had_ref = "ref" in item
        item["ref"] = commit
        if not (had_ref and item.ca.items.get("ref")):  # a comment of the author's stays
            item.yaml_add_eol_comment(f"pinned from {was}", "ref")
        done.append(Pinned(spec.key, was, commit))
        report(Progress(f"{spec.key}: {was} → {commit}"))
    if catalogs:
        _report_ros(machine, path, desired, report, lock_timeout=FETCH_LOCK_TIMEOUT
                    if lock_timeout is None else lock_timeout)
    if write and done:
        out = io.StringIO()
        yaml.dump(data, out)
        write_atomic(path, out.getvalue())
    return done


def _report_ros(machine: Machine, path: Path, desired: DesiredState, report: Report, *,
                lock_timeout: float) -> None:
    """The ROS repositories of the app the file (`desired`, as read before its pins were
    changed: the file is not written yet) names, as they resolve now."""
    with apply_lock(machine.layout, timeout=lock_timeout):  # a fetch into the store is a write
        targets = resolve(desired, base_dir=path.resolve().parent, store=machine.store(),
                          fetch=Fetch.OBJECTS, default_user=libpanda_user(machine.layout),
                          root=machine.layout.root)
    sources = {s.name: s for app in targets.apps for s in app.deps.ros}
    if not sources:
        report(Progress("the apps name no ROS repositories"))
        return
    for source in sources.values():
        follows = source.repo.ref or "default branch"
        pinned = "pinned" if source.repo.ref is not None and is_hex_commit(source.repo.ref) \
            else "follows a branch: pin it in the app's catalog"
        report(Progress(f"ros {source.name}: {follows} → {source.commit} ({pinned})"))
