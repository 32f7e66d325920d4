"""How an app runs as a service: the scriptless `command:` / `launch:` of a catalog entry,
its `health:` check, and the user it runs as.

A scriptless app needs no lifecycle scripts: lpam writes the unit itself (reconciler/base/unit.py)
from an argument list — never a shell string, so a value cannot become a command — or from a
roslaunch file of a package in the catkin workspace. Health says when a started app counts
as up: it stayed active for `settle_seconds` without restarting and, when given, `command`
exited 0 within `timeout_seconds`, and, when `can:` is given, its ids were seen on the bus
within `within_seconds`; otherwise the apply rolls back to the previous app.
"""

from __future__ import annotations

import re

from pydantic import BaseModel, ConfigDict, Field, StrictStr, field_validator

from schemas.vehicle import CanHealth

DEFAULT_SETTLE_SECONDS = 10.0
DEFAULT_HEALTH_TIMEOUT = 10.0
ARG_LIMIT = 4096
_LAUNCH = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}/[A-Za-z0-9_][A-Za-z0-9_.-]{0,199}"
                     r"\.launch$")
_USER = re.compile(r"^[a-z_][a-z0-9_-]{0,31}\$?$")


def check_argv(value: list[str], what: str = "command") -> list[str]:
    """A program and its arguments: non-empty strings a unit file can carry.
    The program is a name found on PATH or a path inside the app folder."""
    if not value:
        raise ValueError(f"{what} must list a program and its arguments, e.g. "
                         "[python3, -u, app.py]")
    for index, arg in enumerate(value):
        if arg == "":
            raise ValueError(f"{what}[{index}] is empty")
        if any(c in arg for c in "\x00\n\r"):
            raise ValueError(f"{what}[{index}] contains a NUL byte or a line break")
        if len(arg) > ARG_LIMIT:
            raise ValueError(f"{what}[{index}] is longer than {ARG_LIMIT} characters")
    program = value[0]
    if program.startswith("-"):
        raise ValueError(f"{what}[0] ({program!r}) must be a program, not an option")
    parts = program.split("/")
    if program.startswith("/") or ".." in parts:
        raise ValueError(f"{what}[0] ({program!r}) must be a program on PATH or a path "
                         "inside the app folder (relative, no '..')")
    return value


def check_launch(value: str) -> str:
    if not _LAUNCH.fullmatch(value):
        raise ValueError(f"launch {value!r} must be PACKAGE/FILE.launch (a launch file of "
                         "a package in the catkin workspace, no other folders)")
    return value


def check_user(value: str) -> str:
    if not _USER.fullmatch(value):
        raise ValueError(f"user {value!r} is not a user name (lowercase letters, digits, "
                         "_ and -)")
    return value


class Health(BaseModel):
    """When a started app counts as healthy (module docstring). Unset fields fall back:
    the desired state's `app.health` over the catalog's, then the defaults."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    settle_seconds: float | None = Field(
        default=None, ge=0, le=3600,
        description=f"stay active this long without restarting (default "
        f"{DEFAULT_SETTLE_SECONDS:g}; 0 turns the check off)")
    command: list[StrictStr] | None = Field(
        default=None, description="argv run in the app folder; exit 0 means healthy")
    timeout_seconds: float | None = Field(
        default=None, gt=0, le=3600,
        description=f"how long `command` may take (default {DEFAULT_HEALTH_TIMEOUT:g})")
    can: CanHealth | None = Field(
        default=None, description="CAN ids the app must put on the bus after it starts, "
        "read from the desired state's vehicle source")

    @field_validator("command")
    @classmethod
    def _command(cls, value: list[str] | None) -> list[str] | None:
        return None if value is None else check_argv(value, "health.command")

    def over(self, base: Health | None) -> Health:
        """These settings, with the unset ones taken from `base`."""
        if base is None:
            return self
        return Health(
            settle_seconds=base.settle_seconds if self.settle_seconds is None
            else self.settle_seconds,
            command=base.command if self.command is None else self.command,
            timeout_seconds=base.timeout_seconds if self.timeout_seconds is None
            else self.timeout_seconds,
            can=base.can if self.can is None else self.can,
        )

