"""A saved plan (`lpam plan --out FILE`, `lpam plan --json`): the contract `apply` executes.

The plan names the state record it was computed against (lineage + serial, as Terraform
does) and is sealed with a fingerprint over everything that drives behaviour, so `apply`
can refuse a plan that is stale or was edited by hand. `changes` are for people; `steps`
are what runs. Display fields (`summary`, reasons) never change behaviour.
"""

from __future__ import annotations

from typing import Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field

from schemas.enums import StrEnum

FORMAT_VERSION: Literal[1] = 1


class Action(StrEnum):
    """What a change does to one thing (Terraform's plans/action.go, closed set)."""

    CREATE = "create"
    UPDATE = "update"
    REPLACE = "replace"
    DELETE = "delete"
    NOOP = "no-op"

    @property
    def symbol(self) -> str:
        return {"create": "+", "update": "~", "replace": "-/+", "delete": "-", "no-op": " "}[
            self.value
        ]


class Change(BaseModel):
    """One difference between desired and observed, with a reason a person can read."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: str = Field(description="'repository.<key>' or 'app'")
    action: Action
    reason: str
    before: dict[str, str | bool | dict[str, str] | None] | None = None
    after: dict[str, str | bool | dict[str, str] | None] | None = None
    warnings: list[str] = Field(default_factory=list)


class Phase(StrEnum):
    PREPARE = "prepare"
    CUTOVER = "cutover"
    CLEANUP = "cleanup"


class StepKind(StrEnum):
    CHECKOUT = "checkout"
    APT = "apt"  # install the app's missing apt packages (before the cutover)
    PIP = "pip"  # the virtual environment of the app's pip requirements
    BUILD = "build"  # the catkin build of the app's ROS repositories at their commits
    STAGE = "stage"
    STOP = "stop"
    UNINSTALL = "uninstall"
    INSTALL = "install"
    CONFIGURE = "configure"  # new parameters (or user) for the installed generation
    START = "start"
    VERIFY = "verify"  # the health check of a started app; a failure rolls back
    ADOPT = "adopt"  # the app LPAM installed is the desired one: recorded as lpam's, as it runs
    REMOVE = "remove"


ArgValue = Optional[Union[str, list[str], dict[str, str]]]


class Step(BaseModel):
    """One unit of work of an apply; `id` is unique in a plan and names it in the journal."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: str
    kind: StepKind
    phase: Phase
    args: dict[str, ArgValue]
    needs: list[str] = Field(default_factory=list)


class Plan(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    format_version: Literal[1] = FORMAT_VERSION
    lpam_version: str
    created_at: str
    lineage: str | None = Field(description="state record lineage the plan was made against")
    serial: int = Field(description="state record serial the plan was made against")
    changes: list[Change]
    steps: list[Step]
    summary: str = ""
    offline: bool = Field(
        default=False,
        description="made without network: branches as of the last fetch; never applied",
    )
    fingerprint: str = ""

    @property
    def has_changes(self) -> bool:
        return any(c.action is not Action.NOOP for c in self.changes)
