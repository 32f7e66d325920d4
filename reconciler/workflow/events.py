"""What a use case tells its caller while it works, as values: the CLI prints them, the
agent logs them, a benchmark times them, the Bluetooth service and the shim answer with
them.

A use case never prints. Each event is small and frozen; `Report` is where they go.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Union

if TYPE_CHECKING:  # `lpam --version` and `--help` load no pydantic
    from schemas.plan import Plan


@dataclass(frozen=True)
class Note:
    """Worth telling beside the result (the CLI writes it to stderr as `note: …`)."""

    text: str


@dataclass(frozen=True)
class Fetched:
    """What resolving fetched and what it cost, in one line (the CLI writes it to stderr
    as `note: …`, the agent to its journal). Not a Note: nothing is amiss, and whoever
    watches for notes (a fleet's status, a test of a quiet pass) need not read it."""

    text: str


@dataclass(frozen=True)
class Progress:
    """A step starting (`[3/7] build:… …`), a rollback step, a line of the outcome."""

    text: str


@dataclass(frozen=True)
class Output:
    """A line of a long command's output (apt-get, pip, catkin_make), already in the
    apply log; a terminal shows some of them so a 10-minute build is not silent."""

    line: str


@dataclass(frozen=True)
class Planned:
    """The plan an apply is about to carry out (before any confirmation)."""

    plan: Plan


@dataclass(frozen=True)
class Phase:
    """A phase of planning finished (`resolve`, `observe`, `plan`): benchmarks time them."""

    name: str


Event = Union[Note, Fetched, Progress, Output, Planned, Phase]
Report = Callable[[Event], None]

