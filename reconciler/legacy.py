"""Import an LPAM installation (`/etc/libpanda.d`) as an equivalent desired state v1.

`lpam import-lpam` is how a vehicle moves from the bash tool to lpam. LPAM kept its
intent in four successive formats (reference/lpam-legacy.md), and a Pi may hold any of
them, or leftovers of several:

1. 2023-04: `app` (the current app's name, or `None`) and folders under `apps/`; no list
   of repositories at all (apps came with libpanda). Repositories are taken from clones
   under `apps-repositories/<owner>/<repo>` (branch from `.git/HEAD`), if any.
2. 2023-08-09: `app-manifest.csv`, lines `owner/repo, branch`; current app in `app`.
3. 2023-08-10: `app-manifest.yaml` without `version`, `owner/repo: {branch: X}` at the top
   level; current app in `app`.
4. 2023-08-17 on: `app-manifest.yaml` with `version: 0.0` — the desired-state v0, converted
   by `migrations.desired_state_v0_to_v1` (era 3 is fed through the same step).

The newest format present wins, as it did for LPAM itself; older files are named in the
output's comment header. `apps/*/rosRepositories.csv` pin ROS (catkin) dependencies of an
app, not app repositories: they are only reported.

Split like a pyinfra fact: `gather` does all reading (texts, folder names, git HEADs) and
`convert` is pure, so each format's parser is tested on text alone.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from migrations import desired_state_v0_to_v1, upgrade
from migrations.step import MigrationError
from reconciler.errors import ConfigError
from reconciler.loading import Document, dump, load
from schemas.names import check_app_name, check_owner_repo, check_ref

DEFAULT_ETC_DIR = Path("/etc/libpanda.d")
APP_FILE = "app"
CSV_MANIFEST = "app-manifest.csv"
YAML_MANIFEST = "app-manifest.yaml"
YAML_BACKUP = "app-manifest.yaml.bak"  # LPAM's copy of an era-3 manifest after migrating it
TOP_FILES = (YAML_MANIFEST, CSV_MANIFEST, APP_FILE, YAML_BACKUP)
MAX_BYTES = 1024 * 1024
_HEX40 = re.compile(r"^[0-9a-f]{40}$")
_REPO_HINT = "write owner/repo, e.g. jmscslgroup/libpanda-default-apps"


@dataclass(frozen=True)
class Clone:
    """A clone LPAM made under `apps-repositories/<owner>/<repo>`."""

    owner: str
    repo: str
    head: str | None  # text of .git/HEAD; None when absent or unreadable


@dataclass(frozen=True)
class LpamFiles:
    """Everything `gather` read from an LPAM directory; the only input of `convert`."""

    etc_dir: Path
    texts: Mapping[str, str]  # path relative to etc_dir -> text
    apps: tuple[str, ...] = ()
    clones: tuple[Clone, ...] = ()
    has_apps_dir: bool = False


@dataclass(frozen=True)
class Imported:
    """The converted desired state (plain data) and what to tell the operator about it."""

    desired: dict[str, Any]
    source: Path
    notes: tuple[str, ...]


def import_lpam(etc_dir: Path) -> str:
    """The YAML text of an equivalent desired state v1, with a comment header saying what was
    found and where."""
    from pydantic import ValidationError

    from schemas.desired import DesiredState

    imported = convert(gather(etc_dir))
    try:
        DesiredState.model_validate(imported.desired)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        raise ConfigError(
            f"the imported desired state is invalid at {where}: {first['msg']}",
            path=imported.source, hint="fix the LPAM file, then import again",
        ) from None
    header = "\n".join(_wrap(note) for note in imported.notes)
    return dump(_document(imported.desired), header=header)


# --- reading (the only I/O) ---------------------------------------------------------------


def gather(etc_dir: Path) -> LpamFiles:
    """Read the LPAM files under `etc_dir`; nothing is interpreted here."""
    if not etc_dir.exists():
        raise ConfigError(
            "LPAM directory not found", path=etc_dir,
            hint=f"give the directory LPAM used, e.g. lpam import-lpam {DEFAULT_ETC_DIR}",
        )
    if not etc_dir.is_dir():
        raise ConfigError(
            "not a directory", path=etc_dir,
            hint=f"give LPAM's directory (normally {DEFAULT_ETC_DIR}), not a file in it",
        )
    texts = {name: _read(etc_dir / name) for name in TOP_FILES if (etc_dir / name).is_file()}
    apps_dir = etc_dir / "apps"
    apps = tuple(p.name for p in _subdirs(apps_dir))
    for app in apps:
        ros = apps_dir / app / "rosRepositories.csv"
        if ros.is_file():
            texts[f"apps/{app}/rosRepositories.csv"] = _read(ros)
    clones = tuple(
        Clone(owner.name, repo.name, _head(repo))
        for owner in _subdirs(etc_dir / "apps-repositories")
        for repo in _subdirs(owner)
    )
    return LpamFiles(etc_dir, texts, apps, clones, apps_dir.is_dir())


def _subdirs(directory: Path) -> list[Path]:
    if not directory.is_dir():
        return []
    try:
        entries = sorted(directory.iterdir())
    except OSError as exc:
        raise ConfigError(f"cannot list: {exc.strerror}", path=directory) from None
    return [p for p in entries if p.is_dir() and not p.name.startswith(".")]


def _read(path: Path) -> str:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read: {exc.strerror}", path=path) from None
    if len(raw) > MAX_BYTES:
        raise ConfigError("file is larger than 1 MiB; not an LPAM file", path=path)
    if b"\x00" in raw:
        raise ConfigError("file is binary, not text", path=path, line=1, column=1)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(
            "file is not UTF-8 text", path=path, line=line, column=1, hint="save it as UTF-8"
        ) from None


def _head(clone: Path) -> str | None:
    try:
        return (clone / ".git" / "HEAD").read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None


# --- converting (pure) --------------------------------------------------------------------


def convert(files: LpamFiles) -> Imported:
    """Choose the newest LPAM format present and convert it; notes become the comment header."""
    etc = files.etc_dir
    notes = [
        "Desired state imported from LPAM (libpanda-app-manager) by `lpam import-lpam`.",
        f"LPAM directory: {_show(str(etc))}",
    ]
    if YAML_MANIFEST in files.texts:
        desired, used, more = _from_yaml(files)
    elif CSV_MANIFEST in files.texts:
        repositories, more = parse_manifest_csv(files.texts[CSV_MANIFEST], etc / CSV_MANIFEST)
        app, app_notes = _current_app(files)
        desired = {"version": 1, "repositories": repositories, "app": app}
        used = [CSV_MANIFEST, APP_FILE]
        more = ["Format: app-manifest.csv (LPAM of 2023-08-09)", *more, *app_notes]
    elif APP_FILE in files.texts or files.has_apps_dir or files.clones:
        desired, more = _from_clones(files)
        used = [APP_FILE]
    else:
        raise ConfigError(
            "no LPAM files found (app-manifest.yaml, app-manifest.csv, app, apps/)", path=etc,
            hint=f"give the directory LPAM used, normally {DEFAULT_ETC_DIR}",
        )
    notes += more
    ignored = [name for name in TOP_FILES if name in files.texts and name not in used]
    if ignored:
        notes.append(f"Ignored (older LPAM formats; the newest wins): {', '.join(ignored)}")
    notes += [
        f"{spec['repo']} has no branch: lpam will follow its default branch"
        for spec in desired["repositories"]
        if "ref" not in spec
    ]
    notes += _app_notes(files, desired["app"])
    notes += _clone_notes(files, desired["repositories"], era1=used == [APP_FILE])
    for name, text in files.texts.items():
        if name.endswith("/rosRepositories.csv"):
            notes += ros_notes(name, text)
    notes.append("Review this file, then run `lpam plan` with it.")
    return Imported(desired, etc / used[0], tuple(notes))


def _from_yaml(files: LpamFiles) -> tuple[dict[str, Any], list[str], list[str]]:
    path = files.etc_dir / YAML_MANIFEST
    doc = load(path, files.texts[YAML_MANIFEST])
    data = {} if doc.data is None else doc.data
    if not isinstance(data, dict):
        raise doc.error(
            "expected a map of owner/repo: {branch: …} or an LPAM 0.0 manifest",
            hint="LPAM wrote `version: 0.0`, `repositories:` and `current:` here",
        )
    if "version" in data:
        desired = upgrade("desired-state", data, path=path, position=doc.position)
        if str(data["version"]).strip() == "1":
            raise doc.error(
                "this is already an lpam desired state (version 1), not an LPAM manifest",
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
    app, app_notes = _current_app(files)
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
        fields = _fields(line)
        extra = [(column, value) for column, value in fields[2:] if value]
        if extra:
            raise ConfigError(
                f"expected `owner/repo, branch`, found {len(fields)} fields",
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


def _fields(line: str) -> list[tuple[int, str]]:
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


def _current_app(files: LpamFiles) -> tuple[str | None, list[str]]:
    if APP_FILE not in files.texts:
        return None, ["No `app` file: no app was installed."]
    app = parse_app_file(files.texts[APP_FILE], files.etc_dir / APP_FILE)
    return app, [f"Current app (from `app`): {app or 'None (no app installed)'}"]


def _from_clones(files: LpamFiles) -> tuple[dict[str, Any], list[str]]:
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
    app, app_notes = _current_app(files)
    return {"version": 1, "repositories": repositories, "app": app}, notes + app_notes


def branch_of_head(head: str | None) -> tuple[str | None, str]:
    """The ref a clone's `.git/HEAD` is on, and how it was found (for the header)."""
    text = (head or "").strip()
    if text.startswith("ref: refs/heads/"):
        branch = text[len("ref: refs/heads/"):]
        try:
            return check_ref(branch), f"on branch {branch}"
        except ValueError:
            return None, f"on branch {_show(branch)}, not a usable name: default branch"
    if _HEX40.match(text):
        return text, f"detached at {text}: pinned to that commit"
    return None, "branch unknown (no readable .git/HEAD): the default branch"


def _app_notes(files: LpamFiles, app: str | None) -> list[str]:
    if not files.has_apps_dir:
        return []
    shown = ", ".join(_show(name) for name in files.apps) or "none"
    notes = [f"Apps found under apps/: {shown}"]
    if app is not None and app not in files.apps:
        notes.append(f"The current app {app} has no folder under apps/.")
    return notes


def _clone_notes(files: LpamFiles, repositories: list[dict[str, str]], *, era1: bool) -> list[str]:
    if era1:
        return []
    wanted = {spec["repo"]: spec.get("ref") for spec in repositories}
    notes = []
    for clone in files.clones:
        name = f"{_show(clone.owner)}/{_show(clone.repo)}"
        if name not in wanted:
            notes.append(f"apps-repositories/{name} is cloned but not in the manifest: "
                         "not imported")
            continue
        ref, _ = branch_of_head(clone.head)
        if ref is not None and wanted[name] is not None and ref != wanted[name]:
            notes.append(f"apps-repositories/{name} is checked out at {ref}; the manifest "
                         f"says {wanted[name]}, which is what was imported")
    return notes


def parse_ros_csv(text: str) -> tuple[list[tuple[int, str, str]], list[int]]:
    """`owner, repo, commit` lines → (line, owner/repo, commit) pins and unreadable lines."""
    pins: list[tuple[int, str, str]] = []
    bad: list[int] = []
    for number, line in enumerate(text.split("\n"), start=1):
        if not line.strip():
            continue
        fields = [value for _, value in _fields(line)]
        if len(fields) != 3 or not all(fields):
            bad.append(number)
            continue
        pins.append((number, f"{fields[0]}/{fields[1]}", fields[2]))
    return pins, bad


def ros_notes(name: str, text: str) -> list[str]:
    """Header lines for one app's rosRepositories.csv: reported, never imported."""
    pins, bad = parse_ros_csv(text)
    notes = [f"{name} pins ROS repositories (catkin dependencies of that app, not app "
             "repositories; not imported — lpam takes them from the app's catalog):"]
    notes += [f"  {_show(repo)} at {_show(commit)} (line {line})" for line, repo, commit in pins]
    if bad:
        notes.append(f"  unreadable lines skipped: {', '.join(map(str, bad))}")
    return notes


def _wrap(note: str) -> str:
    indent = note[: len(note) - len(note.lstrip(" "))]
    return textwrap.fill(
        note, width=92, subsequent_indent=indent + "    ",
        break_long_words=False, break_on_hyphens=False,
    )


def _show(text: str) -> str:
    """Text from disk made safe for a YAML comment line."""
    return text if text.isprintable() else repr(text)


def _document(desired: dict[str, Any]) -> Any:
    """The desired state as a ruamel map, so the output can explain an empty app."""
    from ruamel.yaml.comments import CommentedMap

    out = CommentedMap()
    out["version"] = desired["version"]
    out["repositories"] = [dict(spec) for spec in desired["repositories"]]
    out["app"] = desired["app"]
    if desired["app"] is None:
        out.yaml_add_eol_comment("no app: LPAM had none installed", "app")
    return out
