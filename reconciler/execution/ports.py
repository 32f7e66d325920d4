"""The ports the executor drives: the repository store, the script runner, the services.

Steps see only these protocols, so the same steps run against the real adapters
(adapters/git.py, adapters/scripts.py) and against the in-memory twins
(adapters/memory.py) that the property tests use to crash an apply after every step.
One contract suite (tests/contract/) holds every implementation to the same behaviour.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

from reconciler.unit import Unit, UnitState


class Store(Protocol):
    """The repository store: one checkout per app repository, objects fetched from remotes."""

    def origin_url(self, key: str) -> str | None: ...

    def has_commit(self, key: str, commit: str) -> bool: ...

    def head(self, key: str) -> str | None: ...

    def local_edits(self, key: str) -> list[str]: ...

    def fetch(self, key: str, url: str) -> None: ...

    def checkout(self, key: str, commit: str) -> None: ...

    def remove(self, key: str) -> None: ...

    def export_folder(self, key: str, commit: str, folder: str, dest: Path) -> str:
        """Copy `commit:folder` into the new directory `dest`; the folder's tree hash."""
        ...


class Scripts(Protocol):
    """Runs one lifecycle script of an app; see adapters/scripts.py for the guarantees."""

    def run(
        self, app: str, app_dir: Path, script: str, params: dict[str, str], *,
        run: str, required: bool = False,
    ) -> bool: ...

    def check(
        self, app: str, app_dir: Path, argv: list[str], params: dict[str, str], *,
        timeout: float,
    ) -> tuple[bool, str]:
        """Run a health check command; (exit 0 within `timeout`, a short reason)."""
        ...


class Services(Protocol):
    """A service manager (adapters/services/): runs units and says what state they are in.

    `install` writes or replaces a unit's definition without starting it; `uninstall` stops
    it and removes the definition (both idempotent). `start`, `stop` and `restart` act now
    and raise ServiceError when the manager refuses; `state` never raises for a unit it does
    not know (`UnitState.known` is False). `logs` returns the unit's last `lines` lines of
    output. `kind` names the backend in status and plans.
    """

    kind: str

    def check(self, unit: Unit) -> None:
        """Refuse (ServiceError) a unit this manager could not run as written, without
        installing or starting anything: called while preparing, before the cutover."""
        ...

    def install(self, unit: Unit) -> None: ...

    def uninstall(self, name: str) -> None: ...

    def start(self, name: str) -> None: ...

    def stop(self, name: str) -> None: ...

    def restart(self, name: str) -> None: ...

    def state(self, name: str) -> UnitState: ...

    def logs(self, name: str, lines: int = 20) -> list[str]: ...
