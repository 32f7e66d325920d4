"""Every path lpam touches, derived from one root.

Tests and the demo pass `--root DIR` (or LPAM_ROOT) so that nothing outside DIR is ever
written; on a vehicle the root is `/`. No other module joins paths onto the root itself.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


@dataclass(frozen=True)
class Layout:
    """The file system map of one lpam installation."""

    root: Path

    @property
    def etc(self) -> Path:
        return self.root / "etc" / "lpam"

    @property
    def desired_state(self) -> Path:
        """Where `plan` and `apply` look when no `-f FILE` is given."""
        return self.etc / "desired-state.yaml"

    @property
    def var(self) -> Path:
        return self.root / "var" / "lib" / "lpam"

    @property
    def repositories(self) -> Path:
        """The repository store: one git checkout per app repository."""
        return self.var / "repositories"

    @property
    def generations(self) -> Path:
        """Immutable copies of app folders, one directory per generation."""
        return self.var / "generations"

    @property
    def state_record(self) -> Path:
        return self.var / "state.json"

    @property
    def journal(self) -> Path:
        return self.var / "journal.jsonl"

    @property
    def lock(self) -> Path:
        return self.var / "apply.lock"

    @property
    def logs(self) -> Path:
        return self.root / "var" / "log" / "lpam"

    @property
    def debug_log(self) -> Path:
        return self.logs / "debug.log"

    def repository_dir(self, key: str) -> Path:
        """The checkout of the repository known as `key` (e.g. `owner/name`)."""
        return self.repositories / slug(key)

    def generation_dir(self, app: str, generation: str) -> Path:
        return self.generations / slug(app) / generation


def slug(key: str) -> str:
    """A single, safe path component for a repository key or app name."""
    cleaned = _UNSAFE.sub("+", key.replace("/", "+")).strip(".")
    return cleaned or "_"
