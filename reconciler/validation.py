"""`lpam validate PATH`: check a desired state, an app catalog, or an app repository folder
without touching the machine, and say in one line what was found."""

from __future__ import annotations

from pathlib import Path

from reconciler.documents import catalog_from, desired_from
from reconciler.errors import ConfigError
from reconciler.loading import load
from schemas.catalog import CATALOG_FILE, Catalog


def validate(path: Path) -> str:
    """What `path` is, in one line; the first fault as a located ConfigError. The document
    is parsed once, then read as the kind its keys say it is."""
    if path.is_dir():
        return _repository(path)
    doc = load(path)
    if isinstance(doc.data, dict) and "apps" in doc.data and "version" not in doc.data:
        catalog = catalog_from(doc)
        return f"OK: {path} is an app catalog with {_names(catalog)}"
    state = desired_from(doc)
    app = state.app.name if state.app else "none"
    return (f"OK: {path} is a desired state (version {state.version}): "
            f"{len(state.repositories)} repositories, app {app}")


def _names(catalog: Catalog) -> str:
    names = ", ".join(a.name for a in catalog.apps)
    return f"{len(catalog.apps)} apps ({names})" if catalog.apps else "no apps"


def _repository(folder: Path) -> str:
    path = folder / CATALOG_FILE
    if not path.is_file():
        raise ConfigError(f"no {CATALOG_FILE} at the top of this folder", path=folder,
                          hint="an app repository lists its apps in libpanda-apps.yaml")
    doc = load(path)
    catalog = catalog_from(doc)
    for index, app in enumerate(catalog.apps):  # the catalog keeps the document's order
        if not (folder / app.path).is_dir():
            raise doc.error(f"app {app.name}: folder {app.path!r} does not exist",
                            ["apps", index, "path"], "create the folder or fix `path:` in the "
                            "catalog")
    return f"OK: {folder} is an app repository with {_names(catalog)}"
