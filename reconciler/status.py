"""`lpam status`: the old tool's `-d` table, read from the state record and git objects.

The catalog and the app files (`service`, `description`…) are read from the git objects
of the recorded commit, never from the working tree: a repository may hold a symbolic
link (`service -> /etc/shadow`, or an app folder linking to `/etc`), and a checkout may be
edited, while a blob is exactly what was committed and a link in git is never followed.
It never loads the graph stack, and reads nothing it does not show.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reconciler.documents import parse_catalog
from reconciler.errors import ConfigError
from reconciler.layout import Layout
from reconciler.state import read_record
from schemas.catalog import CATALOG_FILE, with_folder_files

if TYPE_CHECKING:
    from reconciler.adapters.git import GitStore

SHOWN_FILES = ("description.txt", "service")  # the scripts are not shown, so not read
COLUMNS = ("repository", "ref", "commit", "app", "service", "installed", "running", "description")


@dataclass(frozen=True)
class Row:
    repository: str
    ref: str
    commit: str
    app: str
    service: str
    installed: bool
    running: bool
    description: str


def _folder_files(store: GitStore, key: str, commit: str, folder: str) -> dict[str, bytes]:
    """The app's descriptive files as committed (regular blobs only: links are not read)."""
    files = {}
    for name in SHOWN_FILES:
        data = store.read_file(key, commit, f"{folder.rstrip('/')}/{name}")
        if data is not None:
            files[name] = data
    return files


def rows(layout: Layout) -> list[Row]:
    from reconciler.adapters.git import GitStore

    store = GitStore(layout)
    record = read_record(layout)
    installed = record.app
    table: list[Row] = []
    for repo in record.repositories:
        common = {"repository": repo.key, "ref": repo.ref or "(default)",
                  "commit": repo.commit[:12]}
        if not store.has_commit(repo.key, repo.commit):
            table.append(Row(**common, app="-", service="-", installed=False, running=False,
                             description="(commit missing from the repository store)"))
            continue
        data = store.read_file(repo.key, repo.commit, CATALOG_FILE)
        if data is None:
            table.append(Row(**common, app="-", service="-", installed=False, running=False,
                             description="(no libpanda-apps.yaml)"))
            continue
        label = Path(f"{repo.key}@{repo.commit[:12]}/{CATALOG_FILE}")
        try:
            catalog = parse_catalog(label, data.decode("utf-8", "replace"))
        except ConfigError as exc:
            table.append(Row(**common, app="-", service="-", installed=False, running=False,
                             description=f"(catalog unreadable: {exc.message})"))
            continue
        for app in catalog.apps:
            is_installed = (
                installed is not None and installed.name == app.name
                and installed.repository == repo.key
            )
            commit, folder = (
                (installed.commit, installed.path) if is_installed and installed is not None
                else (repo.commit, app.path)
            )
            app = with_folder_files(app, _folder_files(store, repo.key, commit, folder))
            table.append(Row(
                **common, app=app.name, service=app.service or "-", installed=is_installed,
                running=bool(is_installed and installed is not None and installed.running),
                description=app.description,
            ))
    return table


def as_json(layout: Layout) -> dict[str, Any]:
    record = read_record(layout)
    app = record.app
    return {
        "app": None if app is None else {
            "name": app.name, "repository": app.repository, "commit": app.commit,
            "generation": app.generation, "params": app.params, "running": app.running,
            "status": app.status,
        },
        "repositories": [
            {"key": r.key, "url": r.url, "ref": r.ref, "commit": r.commit}
            for r in record.repositories
        ],
        "apps": [asdict(r) for r in rows(layout)],
        "serial": record.serial,
        "lineage": record.lineage,
    }


def _cell(value: object) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value)


def as_table(layout: Layout) -> str:
    table = rows(layout)
    if not table:
        return "No app repositories. Write a desired state and run `lpam apply`."
    cells = [[_cell(getattr(r, c)) for c in COLUMNS] for r in table]
    header = [c.capitalize() for c in COLUMNS]
    widths = [max(len(h), *(len(row[i]) for row in cells)) for i, h in enumerate(header)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)).rstrip()]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)).rstrip()
              for row in cells]
    return "\n".join(lines)
