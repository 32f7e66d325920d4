"""`lpam status`: the old tool's `-d` table, read from the state record and the checkouts.

Deliberately cheap: it reads files only (the record, each checkout's catalog, the app
folders) and never loads the git or graph stack, so it answers fast on a Pi.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from reconciler.documents import parse_catalog
from reconciler.errors import ConfigError
from reconciler.layout import Layout
from reconciler.state import read_record
from schemas.catalog import APP_FILES, CATALOG_FILE, with_folder_files

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


def _folder_files(folder: Path) -> dict[str, bytes]:
    files = {}
    for name in APP_FILES:
        path = folder / name
        if path.is_file():
            files[name] = path.read_bytes()
    return files


def rows(layout: Layout) -> list[Row]:
    record = read_record(layout)
    installed = record.app
    table: list[Row] = []
    for repo in record.repositories:
        checkout = layout.repository_dir(repo.key)
        common = {"repository": repo.key, "ref": repo.ref or "(default)",
                  "commit": repo.commit[:12]}
        catalog_path = checkout / CATALOG_FILE
        try:
            text = catalog_path.read_text(encoding="utf-8")
            catalog = parse_catalog(catalog_path, text)
        except FileNotFoundError:
            table.append(Row(**common, app="-", service="-", installed=False, running=False,
                             description="(no libpanda-apps.yaml)"))
            continue
        except ConfigError as exc:
            table.append(Row(**common, app="-", service="-", installed=False, running=False,
                             description=f"(catalog unreadable: {exc.message})"))
            continue
        for app in catalog.apps:
            is_installed = (
                installed is not None and installed.name == app.name
                and installed.repository == repo.key
            )
            folder = (
                layout.generation_dir(app.name, installed.generation)
                if is_installed and installed is not None else checkout / app.path
            )
            app = with_folder_files(app, _folder_files(folder))
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
