"""Local overrides: the phone or `libpanda-app-manager` steering a car that follows a fleet.

A car that follows a fleet repository applies the fleet's file on every agent pass. In a
staging area a researcher switches the app from a phone; that edit must hold — applied at
once, shown by `lpam status` and in the car's fleet status, and not undone by the agent's
next pass — until someone ends it: the phone's update (`app_update`), or
`lpam apply --release`. Then the car follows its fleet file again.

Where the edit goes: every local edit is an edit of the desired state lpam applies by
default, `<root>/etc/lpam/desired-state.yaml` (workflow/editing.py). A fleet car usually
has none; the first edit then starts from the fleet's file at the revision the car applied
(its relative URLs and files made absolute, so the copy means what the fleet's file
meant), and the override records that it made the file (`seeded`), so that ending it sets
the copy aside. On a car that follows no fleet, an edit is just an edit: no override.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reconciler.base.errors import LpamError
from reconciler.workflow.events import Progress, Report
from reconciler.workflow.machine import Machine

if TYPE_CHECKING:
    from reconciler.workflow.followed import Followed
    from schemas.override import LocalOverride

# Imported inside functions: the record readers and schemas (pydantic) load only when an override is
# read or begun; editing and inventory import this module (start-up of the shim).


@dataclass(frozen=True)
class Editable:
    """The desired state a local edit starts from: the file it writes, its text now, and
    whether that text was made from the fleet's file (the file does not exist yet)."""

    path: Path
    text: str
    seeded: bool


def follows_fleet(machine: Machine) -> bool:
    """The car's agent follows a fleet repository (`lpam install-agent` wrote its file)."""
    return machine.layout.agent_config.exists()


def active(machine: Machine) -> LocalOverride | None:
    """The override in force, None when the car follows its fleet file (or none)."""
    from reconciler.engine.records.state import read_override

    return read_override(machine.layout)


def editable(machine: Machine) -> Editable:
    """The desired state a local edit starts from (see the module docstring)."""
    from reconciler.base.loading import read_text

    path = machine.layout.desired_state
    if path.exists():
        return Editable(path, read_text(path), seeded=False)
    text = _seed(machine) if follows_fleet(machine) else None
    if text is None:
        raise LpamError(f"there is no desired state to edit ({path} does not exist)",
                        hint="write it (see desired-state.example.yaml), or take over an LPAM "
                        "installation with `lpam import-lpam`; nothing was changed")
    return Editable(path, text, seeded=True)


def _seed(machine: Machine) -> str | None:
    """The fleet's file at the revision the car applied, as text, with its relative URLs
    and files made absolute; None before the agent applied any revision."""
    from reconciler.base.loading import dump, load
    from reconciler.workflow.followed import applied_desired, read_status
    from reconciler.workflow.source import SOURCE_KEY

    found = applied_desired(machine)
    revision = read_status(machine).applied_revision
    if found is None or revision is None:
        return None
    name = found.label.relative_to(found.label.parts[0]).as_posix()
    data = machine.store().read_file(SOURCE_KEY, revision, name)
    if data is None:
        return None
    doc = load(found.label, data.decode("utf-8", "replace"))
    _anchor(doc.tree, found)
    header = (f"Made on this car from the fleet's {name} at {revision[:12]} when it was "
              "first edited here (a local override).\n`lpam apply --release` or the phone's "
              "update ends the override and sets this file aside.")
    return dump(doc.tree, header=header)


def _anchor(tree: Any, found: Followed) -> None:
    """Relative `url:`s as the fleet's file meant them (against the source), relative
    `dbc:`/`log:` files where the agent copied them (its base folder)."""
    repos = tree.get("repositories") if isinstance(tree, dict) else None
    for index, spec in enumerate(found.desired.repositories):
        if isinstance(repos, list) and index < len(repos) and isinstance(repos[index], dict) \
                and "url" in repos[index] and spec.url is not None:
            repos[index]["url"] = spec.url
    vehicle = tree.get("vehicle") if isinstance(tree, dict) else None
    for part, key in (("speed", "dbc"), ("source", "log")):
        node = vehicle.get(part) if isinstance(vehicle, dict) else None
        value = node.get(key) if isinstance(node, dict) else None
        if isinstance(node, dict) and isinstance(value, str) and not value.startswith("/"):
            node[key] = str((found.base_dir / value).resolve())


def begin(machine: Machine, *, by: str, seeded: bool) -> LocalOverride | None:
    """Record that a local edit (by `by`) was applied; on a car that follows no fleet an
    edit is no override (None). The first edit's time and starting point are kept."""
    from reconciler.base.atomic import write_atomic
    from reconciler.workflow.followed import read_status
    from schemas.override import LocalOverride

    if not follows_fleet(machine):
        return None
    now = active(machine)
    made = LocalOverride(
        since=now.since if now else machine.clock().isoformat(timespec="seconds"), by=by,
        edits=now.edits + 1 if now else 1,
        revision=now.revision if now else read_status(machine).applied_revision,
        seeded=now.seeded if now else seeded)
    write_atomic(machine.layout.override, made.model_dump_json(indent=2) + "\n")
    return made


def end(machine: Machine, report: Report) -> LocalOverride | None:
    """End the override in force (None: there was none). A local file the override made
    from the fleet's is set aside (`override-ended.yaml`), so the fleet's file governs
    again; a file the operator wrote before is left where it is."""
    import os

    ended = active(machine)
    if ended is None:
        return None
    if ended.seeded and machine.layout.desired_state.exists():
        os.replace(machine.layout.desired_state, machine.layout.override_ended)
    machine.layout.override.unlink()
    report(Progress(f"Ended the local override ({ended.by}, since {ended.since}); the car "
                    "follows its fleet file again."))
    return ended
