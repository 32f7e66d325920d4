"""Generations: immutable copies of app folders under `var/lib/lpam/generations/<app>/<id>`.

Each generation has a small metadata file beside it (`<id>.json`, a versioned document:
schemas/generation.py GenerationMeta, which core/planning/model.py's `Generation` extends with
its folder only, so the engine's value is that file's model): the app, where it was
copied from (repository, commit, folder, tree) and which lifecycle scripts it had. That
file is what lets lpam act safely without its state record — a lost record still leaves
enough on disk to stop and uninstall the app with its *own* scripts and parameters — and
what tells a missing script apart from one that never existed: `start.sh` deleted by the
app's own `install.sh` is an error, not "nothing to run".

A generation folder that disappeared is copied out of git again (and its tree verified)
before a script of it runs: the app must always be stoppable.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.atomic import fsync_dir, write_atomic
from reconciler.base.errors import ConfigError, StepError
from reconciler.base.layout import Layout, is_generation_id
from reconciler.base.reading import KIB, read_bounded
from reconciler.core.planning.model import Generation as Generation  # re-exported: see below
from reconciler.core.planning.model import GenerationKey
from schemas.kinds import DocumentKind

if TYPE_CHECKING:
    from reconciler.engine.execution.ports import Store

# Imported inside functions: the migrations (no heavy library, ~19 modules) load only when a
# generation's meta file is read; a small start-up gain.

# `Generation` is a value the engine names (engine/execution/ports.py's AppFolders): it lives with
# the planning core's values (core/planning/model.py) so that the engine may import it without
# this module, which writes the disk (.importlinter's folders contract).

SCRIPTS = ("install.sh", "uninstall.sh", "start.sh", "stop.sh")


def stage(layout: Layout, store: Store, gen: Generation) -> Path:
    """Copy the app folder at its commit into place (once) and write its metadata."""
    dest = layout.generation_dir(gen.name, gen.generation)
    if not dest.is_dir():
        _export(layout, store, gen, dest)
    meta = layout.generation_meta(gen.name, gen.generation)
    if read_meta(meta) is None:
        scripts = [s for s in SCRIPTS if os.path.lexists(dest / s)]
        body = gen.model_copy(update={"scripts": scripts})
        write_atomic(meta, json.dumps(body.model_dump(mode="json"), indent=2,
                                      sort_keys=True) + "\n")
    return dest


def ensure(layout: Layout, store: Store, gen: Generation) -> Path:
    """The generation's folder, copied out of git again first if it went missing."""
    dest = layout.generation_dir(gen.name, gen.generation)
    if dest.is_dir():
        return dest
    if not (gen.repository and gen.commit and gen.tree):
        raise StepError(f"{gen.name}: generation {gen.generation} is missing from disk and "
                        "lpam does not know where it came from",
                        hint=f"restore {dest} from a backup")
    _export(layout, store, gen, dest)
    return dest


def _export(layout: Layout, store: Store, gen: Generation, dest: Path) -> None:
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.parent / f".staging-{gen.generation}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tree = store.export_folder(gen.repository, gen.commit, gen.path, tmp)
    if tree != gen.tree:
        shutil.rmtree(tmp, ignore_errors=True)
        raise StepError(f"{gen.name}: the app folder's content ({tree[:12]}) is not what was "
                        f"planned ({gen.tree[:12]})",
                        hint="the repository changed under lpam; run `lpam plan` again")
    os.replace(tmp, dest)
    fsync_dir(dest.parent)


def read_meta(path: Path) -> Generation | None:
    """A generation's metadata (of any version: an unversioned file is version 0), or None
    when it is missing, unreadable or invalid (then lpam falls back to what the state
    record says)."""
    from migrations import upgrade

    try:
        data = json.loads(read_bounded(path, limit=64 * KIB, follow_symlinks=False))
        if isinstance(data, dict) and "version" not in data:
            data["version"] = 0
        return Generation.model_validate(
            upgrade(DocumentKind.GENERATION_META, data, path=path))
    except (FileNotFoundError, ConfigError, ValueError, RecursionError):
        return None


def on_disk(layout: Layout) -> Iterator[tuple[str, str]]:
    """(app folder name, generation id) of every generation folder or metadata file."""
    if not layout.generations.is_dir():
        return
    for app_dir in sorted(layout.generations.iterdir()):
        if not app_dir.is_dir() or app_dir.is_symlink() or app_dir.name.startswith("."):
            continue
        ids = {p.name.removesuffix(".json") for p in app_dir.iterdir()}
        for gen in sorted(ids):
            if is_generation_id(gen):
                yield app_dir.name, gen


def present(layout: Layout) -> frozenset[GenerationKey]:
    """The generations whose folder is on disk (what a plan may reuse without staging)."""
    return frozenset(GenerationKey(folder, gen) for folder, gen in on_disk(layout)
                     if layout.generation_dir(folder, gen).is_dir())


def installed_on_disk(layout: Layout) -> list[Generation]:
    """Every generation on disk, read as possibly installed (used when there is no record)."""
    found = []
    for folder, gen in on_disk(layout):
        meta = read_meta(layout.generation_meta(folder, gen))
        found.append(meta if meta is not None else Generation(name=folder, generation=gen))
    return found


def prune(layout: Layout, keep: Collection[tuple[str, str]]) -> None:
    """Delete every generation whose (app folder, id) is not in `keep`, metadata included."""
    for folder, gen in list(on_disk(layout)):
        if (folder, gen) in keep:
            continue
        base = layout.generations / folder
        shutil.rmtree(base / gen, ignore_errors=True)
        (base / f"{gen}.json").unlink(missing_ok=True)
        with contextlib.suppress(OSError):
            base.rmdir()  # only when it was the app's last generation
