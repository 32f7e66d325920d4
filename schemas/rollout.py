"""A rollout: which cars take a new revision of the fleet repository first, and the proof
the next ones wait for (issue 34).

Declared in the desired state a car follows, so it travels with the revision it governs:
the commit that changes the controller says, in the same file, who gets it first. No
controller runs anywhere: each car's agent reads the statuses the cars ahead of it
published (`status/<vehicle>` branches) and decides for itself (core/rollout.py).

A car publishes where it stands (`RolloutState`) inside its agent status, so the fleet and
the other cars read it from the status file they already read.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictStr, field_validator

_PATTERN = re.compile(r"^[A-Za-z0-9_.*?\[\]!-]{1,63}$")


class RolloutSpec(BaseModel):
    """`rollout:` of a desired state."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    waves: list[list[StrictStr]] = Field(
        min_length=1, description="vehicle ids or globs (`rav4-*`, `*`), wave by wave; a "
        "car is in the first wave that names it, and a car no wave names never takes a "
        "revision this rollout governs")
    prove_seconds: float = Field(
        default=600, ge=0, le=30 * 86400, description="how long every car of a wave runs "
        "the revision, its health proven and with no rollback, before the next wave's turn")
    silent_seconds: float | None = Field(
        default=None, gt=0, description="a car with no report for this long is skipped; "
        "absent: a silent car blocks the waves after its own")

    @field_validator("waves")
    @classmethod
    def _waves(cls, value: list[list[str]]) -> list[list[str]]:
        seen: set[str] = set()
        for number, wave in enumerate(value, 1):
            if not wave:
                raise ValueError(f"wave {number} is empty: name at least one vehicle id or "
                                 "glob, or remove the wave")
            for pattern in wave:
                if not _PATTERN.match(pattern) or ".." in pattern:
                    raise ValueError(f"{pattern!r} in wave {number}: a vehicle id or a glob "
                                     "of one (letters, digits, '_', '-', '.', '*', '?', [])")
                if pattern in seen:
                    raise ValueError(f"{pattern!r} is named twice; a car belongs to one wave")
                seen.add(pattern)
        return value


RolloutStage = Literal["waiting", "halted", "proving", "proven", "rolled back"]


class RolloutState(BaseModel):
    """Where this car stands in the rollout of `revision` (the revision its source's branch
    points at): `waiting` for its wave's turn, `halted` by a rollback in an earlier wave,
    `proving` (it runs the revision, not yet `prove_seconds`), `proven`, or `rolled back`
    (its own attempt failed: the waves after its own halt)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    revision: str
    wave: int | None = Field(description="1 for the first wave; None: no wave names it")
    stage: RolloutStage
    since: str = Field(description="when the car entered this stage (its clock)")
    reason: str | None = Field(default=None, description="why it waits or was halted")
    applied: str | None = Field(default=None, description="when it applied the revision "
                                "(proving, proven)")
    boot: str | None = Field(default=None, description="the boot it applied the revision "
                             "in (the kernel's boot id)")
    mono: float | None = Field(default=None, description="seconds since that boot when it "
                               "applied it (CLOCK_BOOTTIME): the proof is measured on this "
                               "clock, never on the wall clock a Pi sets late")
