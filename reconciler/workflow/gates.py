"""Which desired state's update gates govern a command, and the gates now (`lpam gates`).

An apply obeys the gates of the desired state it applies. A command that applies none —
`lpam start|stop|restart|rollback`, `lpam apply PLANFILE` — obeys those of the desired
state in force: `-f FILE` if given, else the default file under the root, else the one the
agent last applied. Decided here, once, so that no caller (the CLI, the Bluetooth service,
the `libpanda-app-manager` shim) can forget the gates or pick other ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import LpamError
from reconciler.workflow.machine import Machine

if TYPE_CHECKING:
    from reconciler.core.vehicle.policy import GateState
    from reconciler.engine.execution.ports import Gate, Listener
    from reconciler.workflow.followed import Followed

# Imported inside functions: the document readers and followed (pydantic) load only when gates
# are checked; operate imports this module at top (a small start-up gain).


@dataclass(frozen=True)
class Governing:
    """The update gates a command obeys (None: ungated) and the bus its health checks
    listen on (None: no desired state is in force)."""

    gate: Gate | None
    listener: Listener | None


def in_force(machine: Machine, file: Path | None) -> Followed | None:
    """The desired state in force (see the module): `file`, else the default file, else
    the agent's. One that cannot be read leaves the gates unknown, which is refused rather
    than guessed; `file` given but absent: none."""
    from reconciler.core.documents import load_desired_document
    from reconciler.workflow.followed import Followed, applied_desired

    path = file if file is not None else machine.layout.desired_state
    try:
        if path.exists():
            return Followed.of(load_desired_document(path), path.resolve().parent)
        return None if file is not None else applied_desired(machine)
    except LpamError as exc:  # raised as it is, so a document's file:line:col stays
        exc.hint = ((exc.hint + "; ") if exc.hint else "") + (
            "the update gates cannot be known: fix it, or pass --force to ignore them "
            "(the vehicle may be moving)")
        raise


def governing(machine: Machine, file: Path | None, *, force: bool = False) -> Governing:
    """The gates and bus of the desired state in force; `force` ignores the gates (the
    operator said the vehicle may be moving) and reads nothing."""
    found = None if force else in_force(machine, file)
    if found is None:
        return Governing(None, None)
    return Governing(machine.gate_for(found.desired, found.base_dir),
                     machine.listener_for(found.desired, found.base_dir))


@dataclass(frozen=True)
class GatesNow:
    """Each update gate of the desired state at `path` now; `gated`: it declares any."""

    path: Path
    gated: bool
    states: list[GateState]

    @property
    def open(self) -> bool:
        return all(s.open for s in self.states)


def gates_now(machine: Machine, path: Path) -> GatesNow:
    """`lpam gates`: the update gates of the desired state at `path`, asked now."""
    from reconciler.core.documents import load_desired

    desired = load_desired(path)
    gate = machine.gate_for(desired, path.resolve().parent)
    return GatesNow(path, gate is not None, list(gate.states()) if gate is not None else [])
