"""A saved plan (`lpam plan --out FILE`, `lpam plan --json`): the contract `apply` executes.

The plan names the state record it was computed against (lineage + serial, as Terraform
does) and is sealed with a fingerprint over everything that drives behaviour, so `apply`
can refuse a plan that is stale or was edited by hand. `changes` are for people; `steps`
are what runs. Version 2 types each kind of step (version 1 carried every step's
arguments as strings, parsed when the step ran); migrations/plan_v1_to_v2.py carries a
saved version-1 plan forward. Display fields (`summary`, reasons) never change behaviour.
"""

from __future__ import annotations

import hashlib
import json
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.enums import StrEnum
from schemas.generation import AppGeneration, StrayGeneration

FORMAT_VERSION: Literal[2] = 2


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


class FetchedRepository(BaseModel):
    """What making the plan fetched for one repository: on a phone's hotspot or a metered
    link, what an update costs."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    key: str
    bytes: int = Field(description="bytes of pack the server sent (a local path: stored)")
    shallow: bool = Field(description="the pinned commit alone, without its history")


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


class _Step(BaseModel):
    """What every step has: `id` is unique in a plan and names it in the journal."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: str
    phase: Phase
    needs: list[str] = Field(default_factory=list)


class CheckoutStep(_Step):
    """A repository of the store checked out at `commit` (None: known after a fetch, in a
    plan made offline, which is never applied)."""

    kind: Literal[StepKind.CHECKOUT] = StepKind.CHECKOUT
    key: str
    url: str
    ref: str | None
    commit: str | None


class RemoveStep(_Step):
    kind: Literal[StepKind.REMOVE] = StepKind.REMOVE
    key: str


class AptStep(_Step):
    kind: Literal[StepKind.APT] = StepKind.APT
    app: str
    packages: list[str]


class PipStep(_Step):
    kind: Literal[StepKind.PIP] = StepKind.PIP
    app: str
    requirements: list[str]


class BuildStep(_Step):
    """The catkin build `build` of the app's ROS repositories (`ros`: name → commit, each
    fetched by its store key from its URL) in `workspace`, as `user`."""

    kind: Literal[StepKind.BUILD] = StepKind.BUILD
    app: str
    build: str
    workspace: str
    user: str
    ros: dict[str, str]
    ros_keys: dict[str, str]
    ros_urls: dict[str, str]

    @model_validator(mode="after")
    def _every_source_found(self) -> BuildStep:
        for name in self.ros:
            if name not in self.ros_keys or name not in self.ros_urls:
                raise ValueError(f"ROS repository {name!r} has no store key or URL")
        return self


class _AppStep(_Step):
    """A step on one generation of the app; `good`: whether it counts as good once the
    step ends (core/planning/lifecycle.py decides: it proved good before, or there is nothing
    to check)."""

    app: AppGeneration
    good: bool


class StageStep(_AppStep):
    kind: Literal[StepKind.STAGE] = StepKind.STAGE


class InstallStep(_AppStep):
    kind: Literal[StepKind.INSTALL] = StepKind.INSTALL


class ConfigureStep(_AppStep):
    kind: Literal[StepKind.CONFIGURE] = StepKind.CONFIGURE


class StartStep(_AppStep):
    kind: Literal[StepKind.START] = StepKind.START


class HealthCheck(BaseModel):
    """When the started app counts as healthy (schemas/service.py, defaults applied)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    settle_seconds: float = Field(ge=0, allow_inf_nan=False)
    timeout_seconds: float = Field(gt=0, allow_inf_nan=False)
    command: list[str] | None = None
    can_ids: list[int] = Field(default_factory=list,
                               description="CAN ids the app must put on the bus")
    can_within_seconds: float = Field(default=10.0, gt=0, allow_inf_nan=False)


class VerifyStep(_Step):
    kind: Literal[StepKind.VERIFY] = StepKind.VERIFY
    app: AppGeneration
    health: HealthCheck


class _LeavingStep(_Step):
    """A stop or an uninstall: of the recorded app (`app`), or of an app found installed
    that the record does not own (`stray`); exactly one of the two."""

    app: AppGeneration | None = None
    stray: StrayGeneration | None = None

    @model_validator(mode="after")
    def _one_target(self) -> _LeavingStep:
        if (self.app is None) == (self.stray is None):
            raise ValueError("give either `app` or `stray`")
        return self

    @property
    def target(self) -> AppGeneration | StrayGeneration:
        target = self.app if self.app is not None else self.stray
        assert target is not None
        return target


class StopStep(_LeavingStep):
    kind: Literal[StepKind.STOP] = StepKind.STOP


class UninstallStep(_LeavingStep):
    kind: Literal[StepKind.UNINSTALL] = StepKind.UNINSTALL


class AdoptStep(_Step):
    """LPAM's app (its `folder`) is `app` as it is: recorded as lpam's, running if its unit
    ran (`running`), with no script."""

    kind: Literal[StepKind.ADOPT] = StepKind.ADOPT
    app: AppGeneration
    folder: str
    running: bool


Step = Annotated[
    Union[CheckoutStep, RemoveStep, AptStep, PipStep, BuildStep, StageStep, InstallStep,
          ConfigureStep, StartStep, VerifyStep, StopStep, UninstallStep, AdoptStep],
    Field(discriminator="kind"),
]
"""One unit of work of an apply, by its `kind`: a step of an unknown kind, a missing or
a mistyped field is refused when the plan is loaded."""


class Plan(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    format_version: Literal[2] = FORMAT_VERSION
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
    fetched: list[FetchedRepository] = Field(
        default_factory=list,
        description="what resolving fetched, per repository; not part of the seal",
    )
    fingerprint: str = ""

    @property
    def has_changes(self) -> bool:
        return any(c.action is not Action.NOOP for c in self.changes)


def fingerprint(plan: Plan) -> str:
    """The plan's seal: over what drives behaviour (the record it was made against and the
    steps), never display text, so a reworded reason does not invalidate a plan while an
    edited step does."""
    body = {
        "format_version": plan.format_version,
        "offline": plan.offline,
        "lineage": plan.lineage,
        "serial": plan.serial,
        "steps": [s.model_dump(mode="json") for s in plan.steps],
    }
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()
