"""The comment header of an imported desired state: what was found and where.

Last step of the import before writing: `convert` (in the package) adds these
cross-era notes to those of the era it chose — apps under `apps/`, clones that disagree
with the manifest, the ROS pins of `apps/*/rosRepositories.csv` (reported, never
imported) — and `import_lpam` wraps each note into comment lines.
"""

from __future__ import annotations

import textwrap

from reconciler.engine.records.legacy.eras import branch_of_head, csv_fields
from reconciler.engine.records.legacy.files import LpamFiles, comment_safe


def notes_on_app(files: LpamFiles, app: str | None) -> list[str]:
    if not files.has_apps_dir:
        return []
    shown = ", ".join(comment_safe(name) for name in files.apps) or "none"
    notes = [f"Apps found under apps/: {shown}"]
    if app is not None and app not in files.apps:
        notes.append(f"The current app {app} has no folder under apps/.")
    return notes


def notes_on_clones(
    files: LpamFiles, repositories: list[dict[str, str]], *, era1: bool
) -> list[str]:
    if era1:
        return []
    wanted = {spec["repo"]: spec.get("ref") for spec in repositories}
    notes = []
    for clone in files.clones:
        name = f"{comment_safe(clone.owner)}/{comment_safe(clone.repo)}"
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
        fields = [value for _, value in csv_fields(line)]
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
    notes += [f"  {comment_safe(repo)} at {comment_safe(commit)} (line {line})"
              for line, repo, commit in pins]
    if bad:
        notes.append(f"  unreadable lines skipped: {', '.join(map(str, bad))}")
    return notes


def wrap_note(note: str) -> str:
    indent = note[: len(note) - len(note.lstrip(" "))]
    return textwrap.fill(
        note, width=92, subsequent_indent=indent + "    ",
        break_long_words=False, break_on_hyphens=False,
    )
