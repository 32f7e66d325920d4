"""What a car follows: this vehicle's desired state in the fleet's source repository at a
revision, and the one its agent last applied — read from the store, never the network.

Sync (workflow/sync.py) reads it on every pass; the gates in force (workflow/gates.py),
a local override (workflow/override.py) and `lpam apply --release` read what the agent
applied. It stands below all of them, so none of them imports another to read it.
"""

from __future__ import annotations

import posixpath
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import ConfigError
from reconciler.workflow.machine import Machine
from reconciler.workflow.source import DEFAULT_FILE, SOURCE_KEY, VEHICLE_DIR, desired_at
from schemas.agent import AgentConfig, AgentStatus, check_vehicle

if TYPE_CHECKING:
    from reconciler.core.documents import DesiredDocument
    from schemas.desired import DesiredState

# Imported inside functions: the document readers and state record (~13 modules) load only when
# the applied desired state or agent status is read; the stdlib/base ones are cheap.


def vehicle_id(machine: Machine, config: AgentConfig) -> str:
    """`vehicle:`, else the content of `vehicle_file:` (under --root), else the hostname."""
    if config.vehicle is not None:
        return config.vehicle
    if config.vehicle_file is not None:
        from reconciler.base.reading import read_bounded

        path = machine.layout.under(config.vehicle_file)
        try:
            text = read_bounded(path, limit=256).decode("utf-8", "replace").strip()
        except FileNotFoundError:
            raise ConfigError(f"vehicle_file {config.vehicle_file} does not exist",
                              path=machine.layout.agent_config,
                              hint="write this vehicle's id there, or set `vehicle:`") from None
    else:
        text = socket.gethostname().split(".")[0]
    try:
        return check_vehicle(text)
    except ValueError as exc:
        raise ConfigError(str(exc), path=machine.layout.agent_config,
                          hint="set `vehicle:` in agent.yaml to a valid id") from None


@dataclass(frozen=True)
class Followed:
    """A desired state read from the source at a revision: its label (the file as
    `fleet.git@c92f32f2ab56/desired-state.yaml`, in errors and the record), where its
    relative files (`dbc:`, `log:`) are on this machine, and each app's (line, column)
    in it (a `DesiredDocument`'s `places`; none: faults name the file alone)."""

    label: Path
    desired: DesiredState
    base_dir: Path
    places: tuple[tuple[int, int], ...] = ()

    @classmethod
    def of(cls, document: DesiredDocument, base_dir: Path) -> Followed:
        """The desired state `document` holds, its relative files in `base_dir`."""
        return cls(document.path, document.desired, base_dir, document.places)


def followed(machine: Machine, vehicle: str, revision: str) -> str | None:
    """The file of the source at `revision` that is this vehicle's desired state: its own
    `vehicles/<id>.yaml`, else the fleet's `desired-state.yaml`; None with neither. Read
    from trees alone (no file is read), so it is known even when the file has a fault."""
    store = machine.store()
    if f"{vehicle}.yaml" in store.folder_files(SOURCE_KEY, revision, VEHICLE_DIR):
        return f"{VEHICLE_DIR}/{vehicle}.yaml"
    return DEFAULT_FILE if DEFAULT_FILE in store.folder_files(SOURCE_KEY, revision, "") \
        else None


def desired_of(machine: Machine, config: AgentConfig, vehicle: str,
             revision: str, *, keep: frozenset[str] | None = None) -> Followed:
    """This vehicle's desired state at `revision`, relative URLs made absolute and the
    files it names relative to itself copied out of the source (the copies of revisions
    other than those in `keep` removed; None keeps all)."""
    name = followed(machine, vehicle, revision)
    found = None if name is None else desired_at(machine, config.source.url, revision, name)
    if found is not None:
        assert name is not None
        return Followed.of(found, files_of(machine, revision, name, found.desired, keep=keep))
    raise ConfigError(f"neither {VEHICLE_DIR}/{vehicle}.yaml nor {DEFAULT_FILE} is in the "
                      f"source at {revision[:12]}", path=machine.layout.agent_config,
                      hint=f"commit a desired state for this vehicle ({vehicle}) or for all")


def files_of(machine: Machine, revision: str, name: str, desired: DesiredState, *,
              keep: frozenset[str] | None) -> Path:
    """The folder that stands for `name`'s folder in the source at `revision`: the files
    the desired state names relative to itself (`vehicle.speed.dbc`, `vehicle.source.log`)
    are copied there once, as they were committed."""
    import shutil

    from reconciler.base.atomic import write_atomic

    root = machine.layout.agent_files
    folder = posixpath.dirname(name)
    vehicle = desired.vehicle
    for relative in (vehicle.speed.dbc, vehicle.source.log):
        if relative is None or relative.startswith("/"):
            continue
        path = posixpath.normpath(posixpath.join(folder, relative))
        if path.startswith("../"):
            raise ConfigError(f"{relative} lies outside the desired-state repository",
                              path=name, hint="name a file inside the repository")
        copy = root / revision / path
        data = None if copy.is_file() else machine.store().read_file(SOURCE_KEY, revision,
                                                                      path)
        if data is not None:
            write_atomic(copy, data)
    if keep is not None and root.is_dir():
        for old in root.iterdir():
            if old.name not in keep | {revision}:
                shutil.rmtree(old, ignore_errors=True)
    return root / revision / folder


def applied_desired(machine: Machine) -> Followed | None:
    """The desired state the agent last applied (from the store, no network), for what
    must obey it between passes — an operator's stop obeys its update gates; None on a
    car with no agent or before its first applied pass."""
    from reconciler.core.documents import load_agent

    if not machine.layout.agent_config.exists():
        return None
    config = load_agent(machine.layout.agent_config)
    revision = read_status(machine).applied_revision
    if revision is None:
        return None
    return desired_of(machine, config, vehicle_id(machine, config), revision)


def read_status(machine: Machine) -> AgentStatus:
    from reconciler.engine.records.state import read_agent_status

    return read_agent_status(machine.layout) or AgentStatus()
