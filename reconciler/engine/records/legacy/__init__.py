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
`convert` is pure, so each format's parser is tested on text alone. The package follows
that flow: `files` reads the directory (`gather`), `eras` parses each format, `notes`
words the comment header, and this module chooses the era (`convert`) and writes the
result (`import_lpam`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from reconciler.base.errors import ConfigError
from reconciler.base.loading import dump
from reconciler.engine.records.legacy.eras import (
    branch_of_head,
    current_app,
    from_clones,
    from_yaml,
    parse_app_file,
    parse_manifest_csv,
)
from reconciler.engine.records.legacy.files import (
    APP_FILE,
    CSV_MANIFEST,
    DEFAULT_ETC_DIR,
    TOP_FILES,
    YAML_MANIFEST,
    LpamFiles,
    comment_safe,
    gather,
)
from reconciler.engine.records.legacy.notes import (
    notes_on_app,
    notes_on_clones,
    parse_ros_csv,
    ros_notes,
    wrap_note,
)

# Imported inside functions: pydantic, the v1-to-v2 migration, the desired-state schema and
# ruamel load only when `lpam import` runs; the parsers here need none (start-up).

__all__ = [  # the package's own flow, and the parsers tested on text alone
    "Imported",
    "branch_of_head",
    "convert",
    "gather",
    "import_lpam",
    "parse_app_file",
    "parse_manifest_csv",
    "parse_ros_csv",
]


@dataclass(frozen=True)
class Imported:
    """The converted desired state (plain data) and what to tell the operator about it;
    `branches`: the branch of each repository pinned to the commit LPAM's clone holds,
    kept beside the pin as a comment."""

    desired: dict[str, Any]
    source: Path
    notes: tuple[str, ...]
    branches: dict[str, str] = field(default_factory=dict)


def import_lpam(etc_dir: Path) -> str:
    """The YAML text of an equivalent desired state v1, with a comment header saying what was
    found and where."""
    from pydantic import ValidationError

    from migrations.desired_state_v1_to_v2 import upgrade
    from schemas.desired import DesiredState

    imported = convert(gather(etc_dir))
    try:  # written as version 1, the field's dialect; checked as lpam reads it
        DesiredState.model_validate(upgrade(imported.desired))
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = list(first["loc"])
        loc = ["app", *loc[2:]] if loc[:1] == ["apps"] else loc
        where = ".".join(str(part) for part in loc)
        raise ConfigError(
            f"the imported desired state is invalid at {where}: {first['msg']}",
            path=imported.source, hint="fix the LPAM file, then import again",
        ) from None
    header = "\n".join(wrap_note(note) for note in imported.notes)
    return dump(_document(imported.desired, imported.branches), header=header)


# --- converting (pure) --------------------------------------------------------------------


def convert(files: LpamFiles) -> Imported:
    """Choose the newest LPAM format present and convert it; notes become the comment header."""
    etc = files.etc_dir
    notes = [
        "Desired state imported from LPAM (libpanda-app-manager) by `lpam import-lpam`.",
        f"LPAM directory: {comment_safe(str(etc))}",
    ]
    if YAML_MANIFEST in files.texts:
        desired, used, more = from_yaml(files)
    elif CSV_MANIFEST in files.texts:
        repositories, more = parse_manifest_csv(files.texts[CSV_MANIFEST], etc / CSV_MANIFEST)
        app, app_notes = current_app(files)
        desired = {"version": 1, "repositories": repositories, "app": app}
        used = [CSV_MANIFEST, APP_FILE]
        more = ["Format: app-manifest.csv (LPAM of 2023-08-09)", *more, *app_notes]
    elif APP_FILE in files.texts or files.has_apps_dir or files.clones:
        desired, more = from_clones(files)
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
    notes += notes_on_app(files, desired["app"])
    notes += notes_on_clones(files, desired["repositories"], era1=used == [APP_FILE])
    notes += [note for name, text in files.texts.items()
              if name.endswith("/rosRepositories.csv") for note in ros_notes(name, text)]
    branches = _pin_to_clones(desired["repositories"], files)
    if branches:
        notes.append("Repositories are pinned to the commit LPAM's clone holds (the branch "
                     "is kept as a comment): lpam takes over what is installed as it is, "
                     "then follows the branch once you write it back as the ref.")
    notes.append("Review this file, then run `lpam plan` with it.")
    return Imported(desired, etc / used[0], tuple(notes), branches)


def _pin_to_clones(repositories: list[dict[str, str]], files: LpamFiles) -> dict[str, str]:
    """Each repository LPAM has a clone of is pinned to the commit that clone holds: the
    apps LPAM installed came from there, so an app already installed from it is the
    desired one and is adopted without a restart. Returns repository → its branch."""
    commits = {f"{c.owner}/{c.repo}": c.commit for c in files.clones if c.commit}
    branches = {}
    for spec in repositories:
        commit = commits.get(spec["repo"])
        if commit is None or spec.get("ref") == commit:  # none, or already that commit
            continue
        branches[spec["repo"]] = spec.get("ref") or "the default branch"
        spec["ref"] = commit
    return branches


def _document(desired: dict[str, Any], branches: dict[str, str]) -> Any:
    """The desired state as a ruamel map, so the output can explain an empty app and say
    which branch a pinned repository follows."""
    from ruamel.yaml.comments import CommentedMap

    out = CommentedMap()
    out["version"] = desired["version"]
    repositories = []
    for spec in desired["repositories"]:
        entry = CommentedMap(spec)
        branch = branches.get(spec["repo"])
        if branch is not None:
            entry.yaml_add_eol_comment(f"{comment_safe(branch)}: where LPAM's clone was", "ref")
        repositories.append(entry)
    out["repositories"] = repositories
    out["app"] = desired["app"]
    if desired["app"] is None:
        out.yaml_add_eol_comment("no app: LPAM had none installed", "app")
    return out
