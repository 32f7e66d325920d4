"""The ports the executor drives: the repository store and the script runner.

Steps see only these protocols, so the same steps run against the real adapters
(adapters/git.py, adapters/scripts.py) and against the in-memory twins
(adapters/memory.py) that the property tests use to crash an apply after every step.
One contract suite (tests/contract/) holds every implementation to the same behaviour.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol


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
