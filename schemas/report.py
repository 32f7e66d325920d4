"""The status report: what a car is, built once (reconciler/report/build.py) and rendered
by every face that tells it — `lpam status` (table and `--json`), `libpanda-app-manager
-d/-c/-t`, the phone's `A` and summary, and the status a car publishes to its fleet.

One value, so that no face re-derives what another already derived, and none reads
another's output back: the table and the phone cannot disagree about an app if both print
the same field. Version 1 is what `lpam status --json` prints, plus `version`; the keys it
printed before the report existed keep their meaning (`app` is the first installed app,
`installed` every one, `apps` every app of every recorded repository).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas.agent import AgentStatus
from schemas.bluetooth import BleService
from schemas.fleet import PublishedApp
from schemas.override import LocalOverride
from schemas.plan import Change
from schemas.record import Actor, AppStatus, Cutover, LastResult

REPORT_VERSION: Literal[1] = 1
NO_SERVICE = "none"  # LPAM's table and the phone: an app that names no service

Standing = Literal["running", "unverified", "stopped by operator", "stopping", "not running",
                   "starting", "installed"]
"""An installed app's status, one closed word, derived together with whether it runs (its
service manager's word) so that no face can say `running` of an app its manager calls
stopped: `running` (its manager says it runs); `unverified` (its manager cannot know its
unit: only lpam's record speaks); `stopped by operator` (`lpam stop`, and it is stopped);
`stopping` (a stop was asked or begun and did not finish: it may still run); `not running`
(lpam started it, its manager says it is not running: drift); `starting` (an install or a
start was under way, or was cut off); `installed` (installed, not started)."""


class _View(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class UnitView(_View):
    """An app's unit as its service manager answered (reconciler/base/unit.py UnitState)."""

    name: str
    known: bool
    active: str = "unknown"
    sub: str = ""
    restarts: int = 0
    pid: int | None = None
    supervised: bool = True
    said: str = Field(description="the unit's state, said")


class InstalledApp(_View):
    """One installed app: what lpam did (the record) and what its manager says now."""

    name: str
    repository: str
    commit: str
    generation: str
    params: dict[str, str] = Field(default_factory=dict)
    running: bool = Field(description="its manager says it runs (the record's word when "
                          "the manager cannot know its unit: then `verified` is false)")
    verified: bool
    status: AppStatus = Field(description="the lifecycle as the record has it")
    standing: Standing = Field(description="its status now, one word of a closed set, "
                               "derived with `running` and `verified`")
    said: str = Field(description="`standing` as a person needs it: what is still owed, "
                      "and by which command")
    held: bool
    rollback_hold: bool = Field(default=False, description="`lpam rollback` holds it at "
                                "this generation: plans propose nothing for it")
    good: bool
    unit: UnitView | None = None
    command: list[str] | None = None
    launch: str | None = None
    user: str | None = None
    claims: list[str] = Field(default_factory=list)
    claims_known: bool = Field(description="false: recorded before lpam knew claims, "
                               "taken as the panda's")

    def published(self) -> PublishedApp:
        """What the fleet sees of it."""
        return PublishedApp(name=self.name, generation=self.generation, status=self.status,
                            running=self.running)


class CatalogRow(_View):
    """An app of a recorded repository (or a note about the repository), as LPAM's `-d`
    table listed them: installed or not."""

    repository: str
    ref: str
    commit: str
    app: str = Field(description="`-`: the row is a note about the repository")
    service: str
    installed: bool
    running: bool
    status: AppStatus | None = Field(description="the installed app's lifecycle as the "
                                     "record has it (InstalledApp.status); None: not "
                                     "installed")
    standing: Standing | None = Field(default=None, description="the installed app's "
                                      "status now (InstalledApp.standing); None: not "
                                      "installed")
    said: str | None = Field(default=None, description="`standing` said, as the table's "
                             "Status column shows it (InstalledApp.said)")
    description: str
    verified: bool | None = None
    damage: str | None = Field(default=None, description="what is wrong with the "
                               "repository's copy in the store")

    @property
    def named_service(self) -> str:
        """The service as LPAM's table and the phone show it: `none` when the app names
        none (no `service` file, no program lpam runs), never an empty field, which reads
        as a column lost or a value not known."""
        return NO_SERVICE if self.service == "-" else self.service


class HoldView(_View):
    kind: Literal["rollback", "operator stop"]
    what: str
    against: str
    ends: str


class RepositoryView(_View):
    key: str
    url: str
    ref: str | None
    commit: str


class Checkout(_View):
    """A repository an apply that did not succeed moved: not what runs."""

    key: str
    commit: str
    applied_commit: str | None


StrayFate = Literal["adopted", "replaced", "known after fetch"]


class StrayView(_View):
    """An app installed without lpam's record (LPAM's, or one whose record was lost), and
    what the next apply does with it: as plan and apply decide it (the same observation)."""

    name: str
    generation: str
    stopped: bool
    pending: str | None
    fate: StrayFate = Field(
        default="replaced", description="adopted: it is a desired app as it is, taken over "
        "in place (no script runs, it is not restarted); replaced: stopped and uninstalled "
        "with its own scripts before any app is installed; known after fetch: which of the "
        "two, `lpam plan` tells once it has fetched the desired commits")
    adopted_as: str | None = Field(default=None, description="the desired app it is")


LastApplyState = Literal["in progress", "deferred", "interrupted", "cut off", "succeeded",
                         "failed", "rolled back"]
"""The last apply as it stands now: one of these, never two. The record's `result`, with
an apply `in progress` whose process is gone read as `cut off` (never written: derived,
reconciler/report/build.py `last_state`)."""


class LastApplyView(_View):
    time: str
    result: LastResult = Field(description="as the state record has it")
    state: LastApplyState = Field(description="as it stands now: `in progress` only while "
                                  "its process lives, else `cut off`")
    reason: str | None = None
    pid: int | None = None
    command: str | None = None
    gates: list[str] = Field(default_factory=list, description="deferred: the gates that "
                             "were closed")
    retry: str | None = Field(default=None, description="deferred: when the agent's next "
                              "pass tries again (None: the next `lpam apply` does)")
    by: Actor | None = Field(default=None, description="who asked for it (None: not "
                             "recorded)")
    shown: str = Field(description="the last apply as it stands now, said")


class Unreadable(_View):
    """A file status reads that is damaged: said, never raised (status always answers)."""

    error: str


class Deferral(_View):
    """The last apply, when a closed update gate deferred its cutover (the state record's
    last apply, so that an apply after it ends it)."""

    time: str
    reason: str
    gates: list[str] = Field(default_factory=list, description="the gates that were closed")
    retry: str | None = Field(default=None, description="when the agent's next pass tries "
                              "again (None: the next `lpam apply` does)")


Writer = Literal["group", "others"]
"""Who besides its owner may write a path: its group, or every other user."""


class ExposedPath(_View):
    """One of lpam's files or directories (or a directory above them) that a user other
    than its owner may change, and so change what lpam runs as root; how to close it
    (reconciler/report/exposure.py decides)."""

    path: str
    what: str = Field(description="what lpam keeps there, or `a directory above lpam's "
                      "files`")
    writable_by: list[Writer] = Field(default_factory=list, description="who besides its "
                                      "owner may write it")
    owner: str | None = Field(default=None, description="its owner, when that is neither "
                              "root nor the user lpam runs as")
    fix: str = Field(description="the command that closes it")
    said: str = Field(description="the path, what is wrong and the fix, said")


class PlanView(_View):
    """What an apply would do now (planned offline): each change and why, or why it is
    not known."""

    summary: str = Field(description="the plan's summary, `no changes`, or why no plan "
                         "could be made")
    changes: list[Change] = Field(default_factory=list)


class StatusReport(_View):
    """The car now. `plan` and `gates` are filled only where a face shows them (the
    phone's summary): planning costs a read of every repository."""

    version: Literal[1] = REPORT_VERSION
    installed: list[InstalledApp] = Field(default_factory=list)
    service_manager: str | None = None
    last_apply: LastApplyView | None = None
    repositories: list[RepositoryView] = Field(default_factory=list)
    checkouts_not_running: list[Checkout] = Field(default_factory=list)
    holds: list[HoldView] = Field(default_factory=list)
    apps: list[CatalogRow] = Field(default_factory=list)
    strays: list[StrayView] = Field(default_factory=list)
    cutover: Cutover | None = None
    serial: int = 0
    lineage: str | None = None
    agent: AgentStatus | Unreadable | None = None
    override: LocalOverride | Unreadable | None = None
    deferred: Deferral | None = None
    plan: PlanView | None = None
    gates: str | None = Field(default=None, description="the update gates now, said")
    exposed: list[ExposedPath] = Field(default_factory=list, description="lpam's files "
                                       "and directories another user may change (empty: "
                                       "none)")
    bluetooth: BleService | None = Field(
        default=None, description="the running `lpam ble` and who may change the car through "
        "it (bonded phones, or any); null when it does not run")

    def listed(self) -> list[CatalogRow]:
        """The rows that are apps, not notes about a repository (LPAM's `-d`, the phone)."""
        return [row for row in self.apps if row.app != "-"]

    @property
    def app(self) -> InstalledApp | None:
        """The first installed app: what readers from before several apps read."""
        return self.installed[0] if self.installed else None
