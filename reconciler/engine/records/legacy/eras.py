"""The pure parsers of each LPAM era, from the texts `files.gather` read.

Second step of the import: `convert` (in the package) picks the newest format present and
hands it here. Era 4 and era 3 (`app-manifest.yaml`, with or without `version: 0.0`) go
through the desired-state v0→v1 migration; era 2 is `app-manifest.csv`; eras 1 to 3 keep
the current app in the `app` file; era 1 has no repository list, so the clones' `.git/HEAD`
stand in for it. Each returns plain data plus lines for the output's comment header.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from migrations import desired_state_v0_to_v1, upgrade
from migrations.step import MigrationError
from reconciler.base.errors import ConfigError
from reconciler.base.loading import Document, load
from reconciler.base.text import counted
from reconciler.engine.records.legacy.files import (
    APP_FILE,
    CSV_MANIFEST,
    HEX40,
    YAML_MANIFEST,
    LpamFiles,
    comment_safe,
)
from schemas.kinds import DocumentKind
from schemas.names import check_app_name, check_owner_repo, check_ref

_REPO_HINT = "write owner/repo, e.g. jmscslgroup/libpanda-default-apps"


def from_yaml(files: LpamFiles) -> tuple[dict[str, Any], list[str], list[str]]:
    path = files.etc_dir / YAML_MANIFEST
    doc = load(path, files.texts[YAML_MANIFEST])
    data = {} if doc.data is None else doc.data
    if not isinstance(data, dict):
        raise doc.error(
            "expected a map of owner/repo: {branch: …} or an LPAM 0.0 manifest",
            hint="LPAM wrote `version: 0.0`, `repositories:` and `current:` here",
        )
    if "version" in data:
        desired = upgrade(DocumentKind.DESIRED_STATE, data, path=path, position=doc.position,
                          to=1)
        if desired["version"] != 1 or str(data["version"]).strip() == "1":
            raise doc.error(
                f"this is already an lpam desired state (version {desired['version']}), not "
                "an LPAM manifest",
                loc=("version",), hint=f"use it as it is: lpam plan -f {path}",
            )
        app = desired["app"] or "None (no app installed)"
        return desired, [YAML_MANIFEST], [
            "Format: app-manifest.yaml with version 0.0 (LPAM of 2023-08-17 onward)",
            f"Current app (from `current:`): {app}",
        ]
    for key in ("repositories", "current"):
        if key in data:
            raise doc.error(
                f"`{key}:` without `version:`", loc=(key,),
                hint="an LPAM manifest with repositories: and current: starts with "
                "`version: 0.0`; add that line",
            )
    desired = _era3(doc, data)
    app, app_notes = current_app(files)
    desired["app"] = app
    notes = ["Format: app-manifest.yaml without version (LPAM of 2023-08-10)", *app_notes]
    return desired, [YAML_MANIFEST, APP_FILE], notes


def _era3(doc: Document, data: dict[str, Any]) -> dict[str, Any]:
    """Era 3 is era 4's `repositories:` map at the top level: reuse the v0→v1 step."""
    try:
        return desired_state_v0_to_v1.upgrade({"version": "0.0", "repositories": data})
    except MigrationError as exc:
        raise doc.error(exc.message, loc=exc.loc[1:], hint=exc.hint) from None


def parse_manifest_csv(text: str, path: Path) -> tuple[list[dict[str, str]], list[str]]:
    """Era 2: `owner/repo, branch` per line. As in LPAM, a repeated repository's last line wins."""
    found: dict[str, dict[str, str]] = {}
    notes: list[str] = []
    for number, line in enumerate(text.split("\n"), start=1):
        line = line.rstrip("\r")
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = csv_fields(line)
        extra = [(column, value) for column, value in fields[2:] if value]
        if extra:
            raise ConfigError(
                f"expected `owner/repo, branch`, found {counted(len(fields), 'field')}",
                path=path, line=number, column=extra[0][0],
                hint="one repository a line: owner/repo, branch",
            )
        (column, repo), (ref_column, ref) = fields[0], [*fields, (0, "")][1]
        _check(check_owner_repo, repo or "", path, number, column, "repository name", _REPO_HINT)
        spec = {"repo": repo}
        if ref:
            _check(check_ref, ref, path, number, ref_column, "branch", None)
            spec["ref"] = ref
        if repo in found:
            notes.append(f"{CSV_MANIFEST} lists {repo} again on line {number}; that line wins")
            del found[repo]
        found[repo] = spec
    return list(found.values()), notes


def csv_fields(line: str) -> list[tuple[int, str]]:
    """Comma-separated fields, stripped, each with the 1-based column where its text starts."""
    out: list[tuple[int, str]] = []
    start = 0
    for part in line.split(","):
        lead = len(part) - len(part.lstrip())
        out.append((start + lead + 1, part.strip()))
        start += len(part) + 1
    return out


def parse_app_file(text: str, path: Path) -> str | None:
    """Eras 1 to 3: the `app` file holds the current app's name, or `None`."""
    lines = [
        (number, line) for number, line in enumerate(text.split("\n"), start=1) if line.strip()
    ]
    if len(lines) > 1:
        raise ConfigError(
            "expected one app name, found a second line", path=path, line=lines[1][0],
            column=1, hint="leave only the current app's name (or None) in this file",
        )
    if not lines:
        return None
    number, line = lines[0]
    name = line.strip()
    if name == "None":
        return None
    column = len(line) - len(line.lstrip()) + 1
    return _check(check_app_name, name, path, number, column, "app name", None)


def _check(
    check: Callable[[str], str],
    value: str, path: Path, line: int, column: int, what: str, hint: str | None
) -> str:
    try:
        result: str = check(value)
    except ValueError as exc:
        shown = repr(value) if value else "nothing"
        raise ConfigError(
            f"{shown} is not a valid {what}", path=path, line=line, column=column,
            hint=hint or str(exc),
        ) from None
    return result


def current_app(files: LpamFiles) -> tuple[str | None, list[str]]:
    if APP_FILE not in files.texts:
        return None, ["No `app` file: no app was installed."]
    app = parse_app_file(files.texts[APP_FILE], files.etc_dir / APP_FILE)
    return app, [f"Current app (from `app`): {app or 'None (no app installed)'}"]


def from_clones(files: LpamFiles) -> tuple[dict[str, Any], list[str]]:
    """Era 1 kept no repository list: the clones on disk are the best evidence there is."""
    repositories: list[dict[str, str]] = []
    notes = ["Format: `app` file and apps/ folders only (LPAM of 2023-04)"]
    for clone in files.clones:
        name = f"{clone.owner}/{clone.repo}"
        try:
            check_owner_repo(name)
        except ValueError:
            raise ConfigError(
                f"{name!r} is not a valid repository name",
                path=files.etc_dir / "apps-repositories" / clone.owner / clone.repo,
                hint="rename or remove that clone, then import again",
            ) from None
        ref, how = branch_of_head(clone.head)
        repositories.append({"repo": name} if ref is None else {"repo": name, "ref": ref})
        notes.append(f"  {name}: {how}")
    if repositories:
        notes.insert(1, "LPAM kept no repository list then; repositories are the clones "
                     "under apps-repositories/:")
    else:
        notes.append("LPAM kept no repository list then and apps-repositories/ has no clones: "
                     "`repositories` is empty. Add the repository that provides your apps "
                     "(e.g. repo: jmscslgroup/libpanda-default-apps) before `lpam plan`.")
    app, app_notes = current_app(files)
    return {"version": 1, "repositories": repositories, "app": app}, notes + app_notes


def branch_of_head(head: str | None) -> tuple[str | None, str]:
    """The ref a clone's `.git/HEAD` is on, and how it was found (for the header)."""
    text = (head or "").strip()
    if text.startswith("ref: refs/heads/"):
        branch = text[len("ref: refs/heads/"):]
        try:
            return check_ref(branch), f"on branch {branch}"
        except ValueError:
            return None, f"on branch {comment_safe(branch)}, not a usable name: default branch"
    if HEX40.fullmatch(text):
        return text, f"detached at {text}: pinned to that commit"
    return None, "branch unknown (no readable .git/HEAD): the default branch"
