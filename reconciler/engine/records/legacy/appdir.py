"""The installed app where LPAM put it: `/etc/libpanda.d/apps/<folder>`, and LPAM's
manifest kept true.

The field's scripts call their helpers by absolute path
(`/etc/libpanda.d/apps/cbf/installRosPackagesForCbf.sh`), so the generation lpam installs
must be reachable there. It is a symlink to the generation folder, switched atomically (a
new link renamed over the old one, then the directory fsynced): at every instant the path
names one whole generation, never a half-copied folder. Whatever script runs is run
through that path, with that path as its working directory.

On a vehicle that used LPAM the path may be LPAM's own copy of the folder (a directory):
it is moved, not deleted, under `var/lib/lpam/replaced/`. There, every other app the
desired repositories offer keeps a folder too, as LPAM's `-p` kept them, so that the old
tool's `-d` and `-i` still work (`keep_offered`). Where LPAM's manifest exists,
its `current:` (and the older `app` file) names the app lpam installed, so LPAM's own
tools and the libpanda scripts that read it still see the truth.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.atomic import fsync_dir, write_atomic
from reconciler.base.errors import ConfigError, LpamError, StepError
from reconciler.base.layout import Layout, slug
from reconciler.base.loading import dump, load
from reconciler.base.reading import read_bounded
from reconciler.base.unit import check_unit_name
from reconciler.core.planning.model import app_folder
from reconciler.engine.records.legacy.files import APP_FILE, MAX_BYTES, YAML_MANIFEST

if TYPE_CHECKING:
    from reconciler.engine.execution.ports import Store
    from schemas.record import StateRecord

# Imported inside functions: the catalog reader and schema load only when the old app's
# catalog is offered; ~10 modules once this module is loaded, a small start-up gain.


def point(layout: Layout, folder: str, target: Path) -> Path:
    """Make `/etc/libpanda.d/apps/<folder>` lead to `target`; returns that path."""
    link = layout.app_link(folder)
    if link.is_symlink() and os.readlink(link) == str(target):
        return link
    link.parent.mkdir(parents=True, exist_ok=True)
    if link.exists() and not link.is_symlink():
        if forget_export(layout, folder):
            shutil.rmtree(link)  # a folder lpam exported itself (keep_offered)
        else:
            _move_aside(layout, link)
    tmp = link.parent / f".{folder}.lpam-{os.getpid()}"
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    os.symlink(target, tmp)
    os.replace(tmp, link)
    fsync_dir(link.parent)
    return link


def release(layout: Layout, folder: str, target: Path) -> None:
    """Remove the link when it still leads to `target` (another generation's is kept)."""
    link = layout.app_link(folder)
    if link.is_symlink() and os.readlink(link) == str(target):
        link.unlink()
        fsync_dir(link.parent)


def _move_aside(layout: Layout, folder: Path) -> None:
    layout.replaced.mkdir(parents=True, exist_ok=True)
    for n in range(1000):
        dest = layout.replaced / (folder.name if n == 0 else f"{folder.name}.{n}")
        if not os.path.lexists(dest):
            os.rename(folder, dest)
            return
    raise StepError(f"cannot move LPAM's folder {folder} aside: {layout.replaced} is full",
                    hint=f"clean up {layout.replaced}")


def set_current(layout: Layout, folder: str | None) -> None:
    """Keep LPAM's record of the current app true, where LPAM left one."""
    manifest = layout.libpanda / YAML_MANIFEST
    if manifest.is_file() and not manifest.is_symlink():
        _set_manifest(manifest, folder)
    app_file = layout.libpanda / APP_FILE
    if app_file.is_file() and not app_file.is_symlink():
        write_atomic(app_file, f"{folder or 'None'}\n")


def _set_manifest(path: Path, folder: str | None) -> None:
    try:
        doc = load(path, read_bounded(path, limit=MAX_BYTES, follow_symlinks=False)
                   .decode("utf-8", "replace"))
    except ConfigError:
        return  # a manifest lpam cannot read is left as it is; LPAM no longer runs here
    data = doc.tree
    if not isinstance(data, dict) or data.get("current") == (folder or "None"):
        return
    data["current"] = folder or "None"
    write_atomic(path, dump(data))


USER_FILE = "libpanda_usr"


def libpanda_user(layout: Layout) -> str | None:
    """The libpanda user (`/etc/libpanda.d/libpanda_usr`): scriptless apps run as it unless
    the desired state says otherwise; None when the file is absent or unreadable."""
    try:
        text = read_bounded(layout.libpanda / USER_FILE, limit=256, follow_symlinks=False)
    except (FileNotFoundError, ConfigError):
        return None
    words = text.decode("utf-8", "replace").split()
    return words[0] if words else None


def lpam_current(layout: Layout) -> str | None:
    """The app LPAM installed on this vehicle, if its folder is still LPAM's own copy: the
    manifest's `current:` (2023-08-17 on), else the older `app` file; None for `None`, a
    name that is not a folder, or a folder that is already lpam's link."""
    name = None
    manifest = layout.libpanda / YAML_MANIFEST
    try:
        if manifest.is_file():
            data = load(manifest, read_bounded(manifest, limit=MAX_BYTES, follow_symlinks=False)
                        .decode("utf-8", "replace")).data
            value = data.get("current") if isinstance(data, dict) else None
            name = value if isinstance(value, str) else None
        if name is None and (layout.libpanda / APP_FILE).is_file():
            text = read_bounded(layout.libpanda / APP_FILE, limit=4096, follow_symlinks=False)
            words = text.decode("utf-8", "replace").split()
            name = words[0] if words else None
    except ConfigError:
        return None
    if name is None or name == "None" or slug(name) != name:
        return None
    folder = layout.libpanda_apps / name
    if folder.is_symlink() or not folder.is_dir():
        return None
    return name


def service_of(folder: Path) -> str | None:
    """The unit an LPAM app's `service` file names (read without following a link); None
    when it has none or names no valid unit."""
    try:
        words = read_bounded(folder / "service", limit=4096, follow_symlinks=False).split()
        return check_unit_name(words[0].decode("utf-8", "replace")) if words else None
    except (FileNotFoundError, NotADirectoryError, ConfigError, ValueError):
        return None


EXPORTED = "exported-folders.json"  # under var/lib/lpam: folders lpam wrote, by commit


def keep_offered(layout: Layout, store: Store, record: StateRecord) -> None:
    """On a vehicle that used LPAM, every app the desired repositories offer keeps its
    folder in `/etc/libpanda.d/apps/`, as LPAM's `-p` left them (its `-d` and `-i` read
    them): a folder missing (an app lpam uninstalled) is exported from the repository at
    its commit, and one lpam exported is refreshed when that commit moved. A folder LPAM
    made is never touched, nor an installed app's link."""
    if not _used_lpam(layout):
        return
    exported = _exported(layout)
    before = dict(exported)
    installed = {app_folder(a.path) for a in record.apps}
    for repo in record.repositories:
        for folder, path in _offered(store, repo.key, repo.commit):
            if folder in installed:
                continue
            place = layout.libpanda_apps / folder
            ours = exported.get(folder)
            if place.is_symlink() and not place.exists():
                place.unlink()  # a generation that is gone
            if place.exists() and (ours is None or ours == repo.commit or place.is_symlink()):
                continue
            _export(layout, store, repo.key, repo.commit, path, place)
            exported[folder] = repo.commit
    if exported != before:
        write_atomic(layout.var / EXPORTED,
                     json.dumps(exported, indent=2, sort_keys=True) + "\n")


def _used_lpam(layout: Layout) -> bool:
    return (layout.libpanda / YAML_MANIFEST).is_file() or (layout.libpanda / APP_FILE).is_file()


def _offered(store: Store, key: str, commit: str) -> list[tuple[str, str]]:
    """(folder, path in the repository) of each app the catalog at `commit` lists."""
    from reconciler.core.documents import parse_catalog
    from schemas.catalog import CATALOG_FILE

    try:
        data = store.read_file(key, commit, CATALOG_FILE)
        if data is None:
            return []
        catalog = parse_catalog(Path(f"{key}@{commit[:12]}/{CATALOG_FILE}"),
                                data.decode("utf-8", "replace"))
    except LpamError:
        return []  # a catalog lpam cannot read offers nothing here; the plan says why
    return [(app_folder(app.path), app.path) for app in catalog.apps]


def _exported(layout: Layout) -> dict[str, str]:
    try:
        data = json.loads(read_bounded(layout.var / EXPORTED, limit=MAX_BYTES,
                                       follow_symlinks=False))
    except (FileNotFoundError, ConfigError, ValueError):
        return {}
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


def _export(layout: Layout, store: Store, key: str, commit: str, path: str,
            place: Path) -> None:
    """The folder at `commit`, put in place whole (exported beside it, then renamed)."""
    tmp = place.parent / f".{place.name}.lpam-export-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        store.export_folder(key, commit, path, tmp)
    except LpamError:
        shutil.rmtree(tmp, ignore_errors=True)
        return  # not there at that commit: nothing to keep
    if place.is_dir() and not place.is_symlink():
        shutil.rmtree(place)  # an older export of lpam's own
    os.replace(tmp, place)
    fsync_dir(place.parent)


def forget_export(layout: Layout, folder: str) -> bool:
    """Whether the folder at `folder`'s place is one lpam exported (then it is lpam's to
    replace with the installed app's link, not LPAM's to keep aside)."""
    exported = _exported(layout)
    if folder not in exported:
        return False
    del exported[folder]
    write_atomic(layout.var / EXPORTED, json.dumps(exported, indent=2, sort_keys=True) + "\n")
    return True
