"""The values the pure planning core works on.

`Targets` is the desired state resolved to commits (by engine/observe/targets.py, which may ask a
remote); `Observed` is what the read-only probes saw on the machine. Both are plain frozen
values, so the diff and the step graph can be tested without git, disk or processes.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import NamedTuple

from reconciler.base.layout import slug
from reconciler.base.unit import UnitState
from schemas.generation import GenerationMeta
from schemas.record import StateRecord

UNKNOWN = "(known after fetch)"  # a value a plan cannot know without the network
LIFECYCLE_SCRIPTS = frozenset({"install.sh", "uninstall.sh", "start.sh", "stop.sh"})


class GenerationKey(NamedTuple):
    """A generation folder on disk: (the app's folder name, the generation id).

    Typed and built in one place (`of`) so that an app name and the folder it lives in
    are never compared as loose strings (`alpha.` lives in `alpha`; comparing the name to
    the folder reinstalled it on every apply)."""

    folder: str
    generation: str

    @classmethod
    def of(cls, app: str, generation: str) -> GenerationKey:
        return cls(slug(app), generation)


@dataclass(frozen=True)
class RepoTarget:
    """A desired repository; `commit` is None only when it is known after a fetch.
    `as_of_last_fetch`: the branch or tag was resolved offline, from what the last fetch
    saw; the remote may have moved since."""

    key: str
    url: str
    ref: str | None
    commit: str | None
    as_of_last_fetch: bool = False
    no_catalog: bool = False  # an app repository whose commit has no libpanda-apps.yaml
    in_store: bool = False  # a pinned commit the store holds: its checkout needs no network
    fetched: int | None = None  # bytes fetched to resolve it (None: no fetch)
    fetched_alone: bool = False  # the fetch brought the commit without its history


@dataclass(frozen=True)
class HealthTarget:
    """When the started app counts as healthy (schemas/service.py), defaults applied."""

    settle_seconds: float = 10.0
    command: tuple[str, ...] | None = None
    timeout_seconds: float = 10.0
    can_ids: tuple[int, ...] = ()  # CAN ids the app must put on the bus after it starts
    can_within: float = 10.0


@dataclass(frozen=True)
class RosSource:
    """One of the app's ROS repositories, resolved like an app repository (`repo`, whose
    key names it in the store) and checked out as `src/<name>` of its build."""

    name: str
    repo: RepoTarget

    @property
    def key(self) -> str:
        return self.repo.key

    @property
    def url(self) -> str:
        return self.repo.url

    @property
    def commit(self) -> str | None:
        return self.repo.commit


@dataclass(frozen=True)
class WorkspaceTarget:
    """The catkin workspace (`ros:` of the desired state, defaults applied) and the user
    its builds run as; `path` is absolute on this machine (under --root)."""

    path: str
    user: str


@dataclass(frozen=True)
class Deps:
    """What the app needs besides its folder, from its catalog entry: apt packages, pip
    requirements (its virtual environment) and ROS repositories (its catkin build)."""

    apt: tuple[str, ...] = ()
    pip: tuple[str, ...] = ()
    ros: tuple[RosSource, ...] = ()
    workspace: WorkspaceTarget | None = None  # where `ros` is built; not part of the id

    @property
    def ros_build(self) -> str | None:
        """The build of the workspace these sources make: one per set of commits, shared by
        every generation that needs the same; None without ROS repositories or while a
        commit is unknown."""
        if not self.ros or any(r.commit is None for r in self.ros):
            return None
        return build_key({r.name: r.commit or "" for r in self.ros})

    @property
    def known(self) -> bool:
        return all(r.commit is not None for r in self.ros)

    @property
    def how(self) -> dict[str, str]:
        """Their part of the generation id: empty for an app without dependencies, so
        generation ids from before dependencies were known do not change."""
        how = {}
        if self.apt:
            how["apt"] = json.dumps(sorted(self.apt))
        if self.pip:
            how["pip"] = json.dumps(sorted(self.pip))
        if self.ros:
            how["ros"] = json.dumps({r.name: r.commit for r in self.ros}, sort_keys=True)
        return how


@dataclass(frozen=True)
class AppTarget:
    """The desired app, the planner's input from the desired state: what it should run
    and how it is checked (`health`) and what it depends on (`deps`, resolved to
    commits). It is not a generation: the planner turns it into a step's
    `AppGeneration` (schemas/generation.py), which the executor stages as a `Generation`
    (below). `tree`/`path` are None when its commit is not fetched yet.

    A script app runs by its lifecycle scripts, and `service` (from its `service` file)
    names the unit whose state says whether it runs. A scriptless app gives `command` or
    `launch`, and lpam writes its unit (run as `user`).

    `resources` are the exclusive resources it claims (core/planning/resources.py): the
    catalog's, and `service:<unit>` for the unit its `service` file names. They shape
    nothing of one app's plan; they only say which desired apps cannot run together."""

    name: str
    repository: str
    commit: str | None
    path: str | None
    tree: str | None
    params: dict[str, str] = field(default_factory=dict)
    service: str | None = None
    command: tuple[str, ...] | None = None
    launch: str | None = None
    user: str | None = None
    health: HealthTarget = field(default_factory=HealthTarget)
    deps: Deps = field(default_factory=Deps)
    resources: frozenset[str] = frozenset()
    data: tuple[str, ...] = ()  # where it writes data files: stamped with what ran
    proven: bool = False  # it proved good before (what a rollback returns to): no re-check
    # the lifecycle scripts its folder has (None: not read), for the plan's words only
    scripts: frozenset[str] | None = None

    @property
    def generation(self) -> str | None:
        """Generation id: the app folder's content, how it runs and what it depends on
        (a new ROS commit is a new build, so a new generation that a rollback can leave).
        Parameters are not part of it: a change of parameters alone restarts the app
        with the new values, without a new generation or its install scripts."""
        if self.tree is None or not self.deps.known:
            return None
        return generation_id(self.tree, self.how)

    @property
    def how(self) -> dict[str, str]:
        """How the app runs and what it needs, as far as it shapes the generation (empty for
        a script app without dependencies)."""
        how = dict(self.deps.how)
        if self.command is not None:
            how["command"] = json.dumps(list(self.command))
        if self.launch is not None:
            how["launch"] = self.launch
        return how

    @property
    def folder(self) -> str | None:
        """The app's folder name in LPAM's layout (/etc/libpanda.d/apps/<folder>)."""
        return None if self.path is None else app_folder(self.path)


@dataclass(frozen=True)
class Targets:
    """The desired repositories and apps, resolved: a set of apps keyed by name, in the
    desired state's order (one app is a set of one)."""

    repositories: tuple[RepoTarget, ...]
    apps: tuple[AppTarget, ...] = ()


@dataclass(frozen=True)
class RepoObserved:
    """A checkout in the repository store as the probe found it."""

    key: str
    present: bool
    head: str | None = None
    origin: str | None = None
    local_edits: tuple[str, ...] = ()


@dataclass(frozen=True)
class Observed:
    """What the read-only probes saw: the state record, each repository's checkout, the
    generations on disk, the steps an interrupted apply left open, each installed app's
    unit as its service manager says (`lives`, by app name), the units of LPAM's apps
    (`stray_live`), each desired app's dependencies on this machine (`deps_by`, by app
    name) and the apps LPAM installed that are desired apps as they are (`adopt`:
    desired app → stray)."""

    record: StateRecord
    repositories: dict[str, RepoObserved]
    generations: frozenset[GenerationKey] = frozenset()
    interrupted: tuple[str, ...] = ()
    lives: dict[str, UnitState] = field(default_factory=dict)
    stray_live: dict[str, UnitState] = field(default_factory=dict)
    deps_by: dict[str, DepsObserved] = field(default_factory=dict)
    adopt: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class DepsObserved:
    """What the desired app's dependencies look like on the machine now: apt packages
    dpkg lacks, requirements its environment would lack (and whether that environment
    exists), whether its ROS build exists, and the ROS commits of the installed app's
    build (to say `17dd12e9 → d7134708`)."""

    apt_missing: tuple[str, ...] = ()
    pip_unsatisfied: tuple[str, ...] = ()
    venv_ready: bool = True
    ros_built: bool = True
    ros_installed: dict[str, str] = field(default_factory=dict)


class Generation(GenerationMeta):
    """A staged generation as the engine works with it: the metadata file beside it on disk
    (schemas/generation.py `GenerationMeta`, read by engine/records/generations.py), built from
    a step's `AppGeneration` and turned into the record's `AppRecord` by field copies, all
    of one family of models (`GenerationFields`). It adds only where its folder lives
    (a rule of lpam's layout, which the schemas do not know), so it writes and reads the
    very same file. `user` stays None: the metadata file never kept it (the record does)."""

    @property
    def folder(self) -> str:
        """Its folder name in LPAM's layout (the app's name when the path is unknown)."""
        return app_folder(self.path) if self.path else slug(self.name)


def build_key(commits: dict[str, str]) -> str:
    """The key of a ROS build: its sources' names and commits."""
    body = json.dumps(commits, sort_keys=True).encode()
    return hashlib.sha256(body).hexdigest()[:16]


def generation_id(tree: str, how: dict[str, str]) -> str:
    digest = hashlib.sha256(json.dumps(how, sort_keys=True).encode()).hexdigest()
    return f"{tree[:12]}-{digest[:8]}"


def app_folder(path: str) -> str:
    """The folder an app lives in, as LPAM named it: the last part of its catalog path."""
    return slug(path.rstrip("/").rsplit("/", 1)[-1])


def short(commit: str | None) -> str:
    return commit[:12] if commit else UNKNOWN
