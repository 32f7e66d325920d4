"""`lpam validate PATH`: check a desired state, an app catalog, or an app repository folder
without touching the machine, and say in one line what was found."""

from __future__ import annotations

from pathlib import Path

from reconciler.documents import load_desired, parse_catalog
from reconciler.errors import ConfigError
from reconciler.loading import load, read_text
from schemas.catalog import CATALOG_FILE, Catalog


def validate(path: Path) -> str:
    if path.is_dir():
        return _repository(path)
    doc = load(path)
    if isinstance(doc.data, dict) and "apps" in doc.data and "version" not in doc.data:
        catalog = parse_catalog(path, read_text(path))
        return f"OK: {path} is an app catalog with {_names(catalog)}"
    state = load_desired(path)
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
    catalog = parse_catalog(path, read_text(path))
    for app in catalog.apps:
        if not (folder / app.path).is_dir():
            raise ConfigError(
                f"app {app.name}: folder {app.path!r} does not exist", path=path,
                hint="create the folder or fix `path:` in the catalog",
            )
    return f"OK: {folder} is an app repository with {_names(catalog)}"
