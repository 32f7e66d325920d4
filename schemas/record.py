"""The state record: what lpam last did to this machine (`var/lib/lpam/state.json`).

Like Terraform's state it has a *lineage* (a UUID fixed when the record is first written)
and a *serial* (incremented on every write), so a saved plan can tell whether the machine
changed since it was made. It is rewritten atomically before and after every script an
apply runs, so after a power cut or a kill it says which scripts finished and which one
may have been under way (the app's `status` and `run`, see reconciler/engine/records/state.py).

Version 4 adds what a fault must not erase (RAUC's rule: a slot is good only once it
proved good): whether the installed app passed its health check (`good`), and the apply
whose cutover is under way (`cutover`: the good app it would return to, and an automatic
rollback once begun), so the next run finishes what a kill interrupted instead of
trusting an app that never proved itself. It also keeps what `lpam status` must not
guess: the desired state of the last apply (`desired`: what holds are held against,
whichever file or revision it came from), each repository's commit as of the last apply
that succeeded (`applied`: a checkout only a failed apply moved is not what runs), and
the last apply's result from its start (`in progress`) — so one that was cut off shows
as such, not as the one before it.

Version 5 keeps a set of installed apps (`apps`, in the order they were installed): a car
may run a controller that owns the panda beside a recorder and a tracker (issue 22). A
cutover returns to the set that ran before (`cutover.previous`), and a rollback names
every app of the apply it undid (`cutover.rollback.failed`).

Version 6 has one model of apps: a car runs a set of apps keyed by name, and one app is a
set of one. A rollback's hold names the set it returns to (`hold.targets`) and nothing
else: version 5's `hold.target` (one app) and `hold.generation` (a name derived from the
set) are gone.

Version 7 makes the last apply a closed state machine: an apply the update gates deferred
ends `deferred` (which gates were closed, and when the agent's next pass tries again),
where version 6 left it `in progress` with a pid that was gone, so that status called it
killed. Whether an apply `in progress` still runs is never written: it is derived from
its pid (gone: it was cut off).

Version 8 says who asked for each change (issue 31: anyone in Bluetooth range of a
parked car could change what it runs): the history entries an apply writes and the last
apply carry `by`, an `Actor` — the user at a terminal (`lpam`, `libpanda-app-manager`),
the phone over Bluetooth (its address, and its name when BlueZ knows it), or the agent
(with the fleet revision it applied). Written only when known: an entry from an older
lpam has none, and reads as "not recorded".
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    model_serializer,
)

from schemas.generation import GenerationFields

CURRENT_VERSION = 8

AppStatus = Literal["installing", "installed", "starting", "running", "stopping", "uninstalling"]
"""Where the installed app's lifecycle stands. The -ing values are written *before* the
script runs (intent before work, as Mender persists its state before each state's work):
after a crash they say which script may have been cut off, so the next apply knows what
to finish, and that the app may hold the CAN hardware even though no script completed."""

ACTIVE: frozenset[str] = frozenset({"starting", "running", "stopping"})
"""Statuses in which the app may have processes on the bus: it is stopped before uninstalling."""


class RepositoryRecord(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    key: str
    url: str
    ref: str | None = Field(description="what the desired state asked for")
    commit: str = Field(description="full hash checked out in the store")
    applied: str | None = Field(
        default=None, description="its commit as of the last apply that succeeded (None: "
        "no successful apply has used it yet): a checkout that differs is not what runs")


ActorKind = Literal["user", "phone", "agent"]


class Actor(BaseModel):
    """Who asked for a change: one value that every caller of the workflow passes (the
    rule that makes it is reconciler/workflow/actor.py), stored where the change is
    recorded. lpam records what reaches it: a phone BlueZ refused (an unbonded phone's
    write to an `encrypt-write` characteristic) never reaches lpam, and is in BlueZ's
    log, not here."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: ActorKind
    id: str | None = Field(
        default=None, description="user: the login name (`SUDO_USER` under sudo); phone: "
        "its Bluetooth address; agent: the fleet revision it applied (None: the car's "
        "local override, or not known)")
    name: str | None = Field(
        default=None, description="phone: its name as BlueZ knows it (None: BlueZ knows "
        "none)")
    via: str | None = Field(
        default=None, description="user: the command it ran (`lpam`, "
        "`libpanda-app-manager`)")

    @model_serializer(mode="wrap")
    def _known_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        data = handler(self)
        if isinstance(data, dict):
            for key in ("id", "name", "via"):
                if data.get(key) is None:
                    data.pop(key, None)
        return data

    @property
    def shown(self) -> str:
        """As `lpam history`, status and the fleet say it: `alice (lpam)`, `phone
        AA:BB:CC:DD:EE:FF (Pixel 7)`, `agent (fleet revision 0123456789ab)`."""
        if self.kind == "phone":
            address = self.id or "(address not known)"
            return f"phone {address}" + (f" ({self.name})" if self.name else "")
        if self.kind == "agent":
            return "agent (" + (f"fleet revision {self.id[:12]}" if self.id
                                else "local override") + ")"
        who = self.id or "(user not known)"
        return who + (f" ({self.via})" if self.via else "")


class AppRecord(GenerationFields):
    """The installed app: the generation (schemas/generation.py) and where its lifecycle
    stands."""

    commit: str = Field(description="commit the installed generation was copied from")
    tree: str = Field(description="git tree hash of the app folder at that commit")
    path: str = Field(description="folder of the app inside its repository")
    status: AppStatus = "installed"
    run: str | None = Field(
        default=None,
        description="id of the script run under way when the status was written; its exit "
        "code lands in var/lib/lpam/runs/<run>.exit when it ends, even if lpam died",
    )
    held: bool = Field(
        default=False, description="stopped by an operator (`lpam stop`): not started again "
        "until `lpam start` or a change of the desired state")
    held_by: Actor | None = Field(
        default=None, description="who stopped it (`held`): the user or the phone; None: "
        "not held, or held by an lpam that did not record it")
    good: bool = Field(
        default=True, description="this generation, with these parameters, passed its "
        "health check to its end since it was installed or reconfigured (or was a good "
        "generation brought back): until then an apply verifies it again, and it is no "
        "rollback target")

    @property
    def running(self) -> bool:
        return self.status == "running"



class Stray(BaseModel):
    """An app generation found installed on disk that no record knew about (the record
    was lost or moved aside). It may hold the CAN hardware, so it is stopped and
    uninstalled with its own scripts before any other app is installed."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    generation: str
    params: dict[str, str] = Field(default_factory=dict)
    stopped: bool = False
    pending: Literal["stop", "uninstall"] | None = Field(
        default=None, description="the script under way when the record was written")
    run: str | None = None
    service: str | None = Field(
        default=None, description="a unit lpam wrote for it (scriptless app): removed with it")
    folder: str | None = Field(
        default=None, description="an app LPAM installed: its folder under "
        "/etc/libpanda.d/apps, whose own scripts stop and uninstall it")




ApplyResult = Literal["applied", "failed", "rolled back"]
LastResult = Literal["applied", "failed", "rolled back", "in progress", "interrupted",
                     "deferred"]
"""How the last apply stands as written. Each is written by one place: `in progress` when
it begins (recovery.begun), `deferred` when a closed gate ends it before its cutover
(recovery.deferred), `interrupted` on Ctrl-C or SIGTERM (recovery.interrupted), the rest
when it ends (recovery.finish). `cut off` is never written: it is an `in progress` whose
process is gone (a kill, a power cut), derived by whoever reads the record."""


class LastApply(BaseModel):
    """How the last apply (or rollback) ended, for `lpam status`: written when it begins
    (`in progress`, with its pid: one whose process is gone was cut off) and when it ends,
    deferred by the gates and interrupted (Ctrl-C, SIGTERM) included."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    time: str
    result: LastResult
    reason: str | None = None
    pid: int | None = Field(default=None, description="the lpam process of an apply in "
                            "progress")
    command: str | None = Field(default=None, description="how to run it again (`lpam "
                                "apply -f FILE`): what an interrupted one's hint says")
    gates: list[str] = Field(default_factory=list, description="a deferred apply: the "
                             "gates that were closed (vehicle, window, lock)")
    retry: str | None = Field(default=None, description="a deferred apply: when the "
                              "agent's next pass tries again (None: nothing tries it "
                              "again by itself; the next `lpam apply` does)")
    by: Actor | None = Field(default=None, description="who asked for it (None: not "
                             "recorded, an lpam before version 8)")

    @model_serializer(mode="wrap")
    def _known_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        """Only a deferral writes its gates and retry, and only a known actor its `by`:
        other results stay as version 6 wrote them."""
        data = handler(self)
        if isinstance(data, dict):
            if not data.get("gates"):
                data.pop("gates", None)
            for key in ("retry", "by"):
                if data.get(key) is None:
                    data.pop(key, None)
        return data


class DesiredRef(BaseModel):
    """The desired state an apply worked toward: holds are held against it, whichever
    file or revision it came from."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    fingerprint: str = Field(description="of its content, not its formatting")
    source: str = Field(description="the file, or `<repository>@<revision>/<file>`")


class HistoryEntry(BaseModel):
    """One generation that was made current, newest last (`lpam history`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    generation: str
    app: str
    repository: str
    commit: str
    path: str
    tree: str
    params: dict[str, str] = Field(default_factory=dict)
    command: list[str] | None = None
    launch: str | None = None
    service: str | None = None
    user: str | None = None
    time: str
    result: ApplyResult
    resources: list[str] | None = Field(
        default=None, description="what the app claimed (None: not known, taken as the "
        "panda); written only when known")
    apply: int | None = Field(
        default=None, description="which apply wrote it (the record's serial then): the "
        "entries of one apply are one set; written only when known (an entry from before "
        "several apps is a set of its own)")
    by: Actor | None = Field(
        default=None, description="who asked for the apply that wrote it (None: not "
        "recorded, an lpam before version 8); written only when known")

    @model_serializer(mode="wrap")
    def _known_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        data = handler(self)
        for key in ("resources", "apply", "by"):
            if isinstance(data, dict) and data.get(key, ()) is None:
                del data[key]
        return data

    @classmethod
    def of(cls, app: AppRecord, *, time: str, result: ApplyResult,
           apply: int | None = None, by: Actor | None = None) -> HistoryEntry:
        return cls(generation=app.generation, app=app.name, repository=app.repository,
                   commit=app.commit, path=app.path, tree=app.tree, params=dict(app.params),
                   command=app.command, launch=app.launch, service=app.service,
                   user=app.user, time=time, result=result, resources=app.resources,
                   apply=apply, by=by)

    def installed(self) -> AppRecord:
        """This generation as the installed app it was (what a rollback returns to)."""
        return AppRecord(name=self.app, repository=self.repository, commit=self.commit,
                         tree=self.tree, path=self.path, params=dict(self.params),
                         generation=self.generation, command=self.command,
                         launch=self.launch, service=self.service, user=self.user,
                         resources=self.resources)


def history_sets(history: list[HistoryEntry]) -> list[list[HistoryEntry]]:
    """The history as the sets of apps each apply made current (or rolled back): the
    entries one apply wrote share its number (`apply`) and result. An entry written before
    several apps is a set of its own."""
    sets: list[list[HistoryEntry]] = []
    for entry in history:
        if sets and entry.apply is not None and \
                (sets[-1][0].apply, sets[-1][0].result) == (entry.apply, entry.result):
            sets[-1].append(entry)
        else:
            sets.append([entry])
    return sets


class Hold(BaseModel):
    """A rollback holds until the desired state changes (`lpam apply --release` ends it)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    desired: str = Field(description="fingerprint of the desired state that was rolled back")
    targets: list[HistoryEntry] = Field(
        default_factory=list, description="the set of apps the rollback returns to: a "
        "rollback cut off by a crash is finished by the next plan and apply (empty: "
        "recorded by an lpam that did not keep it)")
    by: Actor | None = Field(
        default=None, description="who asked for the rollback (None: not recorded)")

    @property
    def name(self) -> str:
        """The set it returns to as a plan and status name it (`app@generation`, one
        generation's id alone for a set of one)."""
        if not self.targets:
            return "an earlier generation"
        if len(self.targets) == 1:
            return self.targets[0].generation
        return ", ".join(f"{e.app}@{e.generation}" for e in self.targets)


class Rollback(BaseModel):
    """An automatic rollback once begun: the app that failed and why. A rollback that a
    fault cut off is finished by the next run, and the failure stays recorded."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    failed: list[AppRecord] = Field(
        default_factory=list, description="the apps the apply installed or changed, as "
        "they stood when its install, start or health check failed (empty: none got "
        "installed)")
    reason: str = Field(description="what failed, as the apply reported it")
    health: bool = Field(default=False, description="it was a failed health check (exit 3)")
    time: str


class Cutover(BaseModel):
    """The cutover of an apply, from its first step until the apply ends (applied, rolled
    back or failed): the good app it returns to if the new one fails — kept across faults,
    so an app that never proved itself is never taken for the one to return to."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    previous: list[AppRecord] = Field(
        default_factory=list, description="the good apps that ran before (empty: none; a "
        "failure removes the new ones)")
    began: str
    rollback: Rollback | None = None


class StateRecord(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[8] = 8
    lineage: str | None = None
    serial: int = 0
    repositories: list[RepositoryRecord] = Field(default_factory=list)
    apps: list[AppRecord] = Field(default_factory=list)
    strays: list[Stray] = Field(default_factory=list)
    last_apply: LastApply | None = None
    history: list[HistoryEntry] = Field(default_factory=list)
    hold: Hold | None = None
    cutover: Cutover | None = None
    desired: DesiredRef | None = None

    def repository(self, key: str) -> RepositoryRecord | None:
        return next((r for r in self.repositories if r.key == key), None)

    def installed(self, name: str) -> AppRecord | None:
        """The installed app of that name (names are unique on a car)."""
        return next((a for a in self.apps if a.name == name), None)

    def with_app(self, name: str, app: AppRecord | None) -> StateRecord:
        """The record with the installed app `name` replaced by `app` (None: removed); a
        new app is added last (the order apps were installed in)."""
        apps = [a for a in self.apps if a.name != name]
        if app is not None:
            at = next((i for i, a in enumerate(self.apps) if a.name == name), len(apps))
            apps.insert(at, app)
        return self.model_copy(update={"apps": apps})
