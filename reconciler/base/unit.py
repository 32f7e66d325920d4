"""Services as lpam sees them, whatever manages them: a unit to run and the state it is in.

An app is a *service*: its long-lived processes are run by a service manager (systemd on a
vehicle, supervisord on a developer machine or in CI, an in-memory twin in fast tests; see
reconciler/engine/execution/ports.py `Services` and reconciler/adapters/services/). lpam writes a
`Unit` itself for a scriptless app (a catalog `command:` or `launch:`); a script app names
in its `service` file a unit that its own scripts create, and lpam only asks its state.

`UnitState` is the answer to "is it running?", asked of the manager rather than taken from
what lpam wrote down: `known` is False when this manager cannot know the unit at all (a
systemd unit name asked of supervisord on a developer machine), and then lpam falls back to
what the scripts reported and says the state is unverified.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

UNIT_PREFIX = "lpam-app-"
_UNIT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.@-]{0,200}")

Activity = Literal["active", "activating", "deactivating", "inactive", "failed", "unknown"]
"""systemd's ActiveState values, which supervisord's states are mapped onto."""


@dataclass(frozen=True)
class Unit:
    """One long-lived program to supervise, as lpam generates it for a scriptless app.

    Both backends render the same promises: restart when it exits unexpectedly (a pause
    between restarts, a start limit), stop and kill as a group (roslaunch has children),
    a bounded stop, the app's parameters as its environment, its output kept (systemd's
    journal; supervisord: `log`)."""

    name: str  # without `.service`: lpam-app-<app>
    argv: tuple[str, ...]
    directory: Path
    environment: dict[str, str] = field(default_factory=dict)
    user: str | None = None  # None: the manager's own user
    description: str = ""
    restart_seconds: float = 2.0
    stop_seconds: float = 10.0
    start_limit: int = 5  # restarts allowed within start_limit_seconds before giving up
    start_limit_seconds: float = 60.0
    log: Path | None = None  # supervisord's output file; systemd uses its journal


@dataclass(frozen=True)
class UnitState:
    """A unit's state now, as its manager reports it."""

    name: str
    known: bool
    active: Activity = "unknown"
    sub: str = ""
    restarts: int = 0
    pid: int | None = None
    supervised: bool = True  # False: its processes run, but the manager that ran them died

    @property
    def running(self) -> bool:
        return self.known and self.active == "active"

    def describe(self) -> str:
        if not self.known:
            return f"unit {self.name} unknown to this service manager"
        if not self.supervised:
            return (f"unit {self.name} still runs (pid {self.pid}) but its service manager "
                    "died: nobody restarts it or keeps its output")
        detail = f" ({self.sub})" if self.sub and self.sub != self.active else ""
        return f"unit {self.name} {self.active}{detail}"


def unit_name(app_folder: str) -> str:
    """The unit lpam generates for a scriptless app (its folder name is already a slug)."""
    return f"{UNIT_PREFIX}{app_folder}"


def check_unit_name(name: str) -> str:
    """A unit name as an app's `service` file gives it (`can`, `pandarecord.service`):
    one word a service manager accepts, never an option or a path."""
    base = name.removesuffix(".service")
    if not _UNIT_NAME.fullmatch(base):
        raise ValueError(f"{name!r} is not a service name (letters, digits, _ . @ -; "
                         "not starting with - or .)")
    return base
