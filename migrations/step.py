"""What every migration step shares: its signature and the one error it may raise.

A step is a pure function from one document version to the next. It never sees a file,
so it cannot report a file position itself; instead it raises `MigrationError` with the
*location inside the old document* (`("repositories", "owner/repo")`), and the registry
(`migrations.upgrade`) or the legacy importer turns that into a `ConfigError` at the
right line and column. This keeps steps free of I/O and still lets users go straight to
the faulty spot.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

Step = Callable[[dict[str, Any]], dict[str, Any]]


class MigrationError(ValueError):
    """The old document cannot be carried forward as it is; `loc` says where it is wrong."""

    def __init__(
        self, message: str, *, loc: tuple[str | int, ...] = (), hint: str | None = None
    ) -> None:
        super().__init__(message)
        self.message = message
        self.loc = loc
        self.hint = hint
