"""The ports the executor drives: the repository store, the script runner, the services.

Steps see only these protocols, so the same steps run against the real adapters
(adapters/git.py, adapters/scripts.py) and against the in-memory twins
(adapters/memory.py) that the property tests use to crash an apply after every step.
One contract suite (tests/contract/) holds every implementation to the same behaviour.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from reconciler.base.errors import RefNotFoundError
from reconciler.base.unit import Unit, UnitState
from schemas.names import is_hex_commit

if TYPE_CHECKING:
    from reconciler.core.planning.model import Generation, GenerationKey
    from reconciler.core.vehicle.policy import GateState
    from schemas.record import StateRecord

DEFAULT_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
"""The PATH a script, a build or a unit runs with when lpam's own has none: part of the
contract between the steps that describe a program and the adapters that run it."""

SOURCE_THEN_EXEC = 'source "$1" || exit 1; shift; exec "$@"'
"""Runs a command inside a ROS environment (a setup.bash), from an argument list: the setup
file and the command are the shell's arguments, never part of its code. Builds use it with
the underlay (adapters/catkin.py), and launch units (engine/execution/supervision.py) with their
build's devel space."""


class Store(Protocol):
    """The repository store: one checkout per app repository, objects fetched from remotes.

    It is a cache of the remotes: a read of a damaged checkout raises StoreDamagedError
    naming it; `damage` says what is wrong (None: sound or absent) without raising, and
    `renew` fetches the repository afresh in place of its checkout, keeping the old one
    aside (its path; None when there was none) and moving nothing when the fetch fails.
    `remove` of a damaged checkout keeps it aside as well."""

    def origin_url(self, key: str) -> str | None: ...

    def damage(self, key: str) -> str | None: ...

    def renew(self, key: str, url: str) -> Path | None: ...

    def has_commit(self, key: str, commit: str) -> bool: ...

    def head(self, key: str) -> str | None: ...

    def local_edits(self, key: str) -> list[str]: ...

    def fetch(self, key: str, url: str, *, want: str | None = None) -> Fetched:
        """Bring `key` up to date with `url` (a clone when absent or when the URL changed):
        the commit `want` alone when given (its tree, not its history: what an app needs),
        else every branch and tag with their history. What came over the wire."""
        ...

    def repoint(self, key: str, url: str) -> None:
        """Make `url` the checkout's origin without the network, for a checkout that already
        holds the commit it needs (a pinned repository moved to another URL): a commit
        names the same content whichever remote brought it. What the last fetch saw of the
        old origin's branches and tags is set aside, never read as the new one's."""
        ...

    def checkout(self, key: str, commit: str) -> None: ...

    def remove(self, key: str) -> None: ...

    def export_folder(self, key: str, commit: str, folder: str, dest: Path) -> str:
        """Copy `commit:folder` into the new directory `dest`; the folder's tree hash."""
        ...

    def read_file(self, key: str, commit: str, path: str) -> bytes | None:
        """The regular file `commit:path` (None without it; a link is not followed)."""
        ...

    def folder_blobs(self, key: str, commit: str, folder: str) -> dict[str, str] | None:
        """Each file under `commit:folder` (its path inside the folder, `/`-separated) and
        its git blob id; None without that folder or with more files than an app has.
        Blob ids name content only, so a copy of the folder on disk can be told equal
        whatever its files' modes (adopting an app LPAM installed)."""
        ...


READ_LIMIT = 4 * 1024 * 1024
"""The most a store's `read_file` returns: app catalogs and parameter files are a few KiB,
and a blob read whole into memory must not be able to exhaust the Pi's."""

HEADS = "refs/heads/"
TAGS = "refs/tags/"


@dataclass(frozen=True)
class Fetched:
    """What one fetch brought: the bytes of pack the server sent (a local path: the bytes
    stored), and whether it was one commit without its history."""

    url: str
    bytes: int = 0
    shallow: bool = False


@dataclass(frozen=True)
class RemoteRefs:
    """What a remote advertises: branch and tag tips (tags peeled to their commit)."""

    url: str
    refs: dict[str, str]
    default_branch: str | None

    def resolve(self, ref: str | None) -> str | None:
        """The commit `ref` names on the remote, or None.

        Short names are tried as a tag before a branch, the order `git rev-parse` uses, so
        that lpam and a user's git agree on an ambiguous name.
        """
        if ref is None:
            return self.refs.get(HEADS + self.default_branch) if self.default_branch else None
        for name in (ref, TAGS + ref, HEADS + ref):
            if name.startswith("refs/") and name in self.refs:
                return self.refs[name]
        if len(ref) == 40 and is_hex_commit(ref) and ref in self.refs.values():
            return ref
        return None


class Resolving(Store, Protocol):
    """The store as resolving a desired state's refs to commits asks it (engine/observe/targets.py):
    what a remote advertises, what the last fetch saw, abbreviated hashes expanded, objects
    fetched without moving a checkout, and a folder's tree. GitStore and MemoryStore both
    implement it, held to one contract (tests/contract/test_store.py)."""

    def location(self, key: str) -> Path: ...

    def read_file(self, key: str, commit: str, path: str, *,
                  limit: int = READ_LIMIT) -> bytes | None:
        """The regular file `commit:path`, at most `limit` bytes (GitError beyond)."""
        ...

    def fetch_objects(self, key: str, url: str, *, want: str | None = None) -> Fetched: ...

    def ls_remote(self, url: str) -> RemoteRefs: ...

    def local_refs(self, key: str) -> RemoteRefs | None: ...

    def resolve_local(self, key: str, ref: str) -> str | None: ...

    def folder_tree(self, key: str, commit: str, folder: str) -> str | None: ...

    def folder_files(self, key: str, commit: str, folder: str) -> list[str]:
        """The names of the regular files directly in `commit:folder` ([] without it)."""
        ...


def ambiguous(key: str, ref: str, commits: Sequence[str]) -> RefNotFoundError:
    """What every store raises when an abbreviated hash names several commits."""
    return RefNotFoundError(
        f"{key}: the abbreviated hash '{ref}' matches {len(commits)} commits: "
        + ", ".join(commits), hint="give more digits of the commit hash")


class AppFolders(Protocol):
    """The app folders on disk: generations (immutable copies of an app folder at a commit,
    under var/lib/lpam/generations, each with its metadata) and the place the field's scripts
    find the installed one (`/etc/libpanda.d/apps/<folder>`, with LPAM's manifest kept true).

    Every change is atomic (a folder exported beside its place then renamed, a link renamed
    over the old one, metadata written whole) and idempotent: a step interrupted anywhere
    and run again converges. The disk implementation is adapters/folders.py, held to
    tests/contract/test_folders.py.
    """

    def stage(self, gen: Generation) -> Path:
        """The generation's folder, exported from the store at its commit when absent (an
        existing folder is kept as it is), and its metadata written when absent or
        unreadable. A tree that is not `gen.tree` is refused (StepError), nothing put in
        place."""
        ...

    def ensure(self, gen: Generation) -> Path:
        """The generation's folder, exported from the store again first if it went missing
        (so that the app stays stoppable). StepError when the exported tree is not
        `gen.tree`, or when `gen` does not say where it came from."""
        ...

    def meta(self, app: str, generation: str) -> Generation | None:
        """The generation as its metadata says (any version); None when missing, unreadable
        or invalid: the caller falls back to what the state record says."""
        ...

    def present(self) -> frozenset[GenerationKey]:
        """The generations whose folder is on disk (what a plan may reuse unstaged)."""
        ...

    def installed(self) -> list[Generation]:
        """Every generation on disk (folder or metadata), from its metadata when readable,
        else only its name and id: what may still be installed."""
        ...

    def prune(self, keep: Collection[GenerationKey]) -> None:
        """Delete every generation not in `keep`, folder and metadata (missing: nothing)."""
        ...

    def point(self, folder: str, target: Path) -> Path:
        """Make `/etc/libpanda.d/apps/<folder>` a link to `target` (switched atomically;
        a folder LPAM left there is moved aside, never deleted); returns that path."""
        ...

    def release(self, folder: str, target: Path) -> None:
        """Remove `folder`'s link only while it still leads to `target` (the link of
        another generation, or a folder, is kept)."""
        ...

    def set_current(self, folder: str | None) -> None:
        """Where LPAM's manifest exists, make it name `folder` as the current app (None:
        none); without one, nothing is written."""
        ...

    def service_of(self, folder: Path) -> str | None:
        """The unit an LPAM app folder's `service` file names; None without a valid one."""
        ...

    def keep_offered(self, record: StateRecord) -> None:
        """On a vehicle that used LPAM, every app the record's repositories offer keeps a
        folder in `/etc/libpanda.d/apps` (exported from the store when missing); a folder
        LPAM made and the installed app's link are never touched."""
        ...


class Scripts(Protocol):
    """Runs one lifecycle script of an app; see adapters/scripts.py for the guarantees."""

    def run(
        self, app: str, app_dir: Path, script: str, params: dict[str, str], *,
        run: str, required: bool = False,
    ) -> bool: ...

    def check(
        self, app: str, app_dir: Path, argv: list[str], params: dict[str, str], *,
        timeout: float,
    ) -> tuple[bool, str]:
        """Run a health check command; (exit 0 within `timeout`, a short reason)."""
        ...


class Services(Protocol):
    """A service manager (adapters/services/): runs units and says what state they are in.

    `install` writes or replaces a unit's definition without starting it; `uninstall` stops
    it and removes the definition (both idempotent). `start`, `stop` and `restart` act now
    and raise ServiceError when the manager refuses; `state` never raises for a unit it does
    not know (`UnitState.known` is False). `logs` returns the unit's last `lines` lines of
    output. `kind` names the backend in status and plans.
    """

    kind: str

    def check(self, unit: Unit) -> None:
        """Refuse (ServiceError) a unit this manager could not run as written, without
        installing or starting anything: called while preparing, before the cutover."""
        ...

    def install(self, unit: Unit) -> None: ...

    def uninstall(self, name: str) -> None: ...

    def start(self, name: str) -> None: ...

    def stop(self, name: str) -> None: ...

    def restart(self, name: str) -> None: ...

    def state(self, name: str) -> UnitState: ...

    def logs(self, name: str, lines: int = 20) -> list[str]: ...


Log = Callable[[str], None]
"""Where an adapter sends the output of a long command (apt, pip, catkin_make), line by
line: the apply log, and the terminal's progress line."""


class Packages(Protocol):
    """The system's package manager (apt): which packages are missing, and installing them.

    `install` installs exactly the names given, in one batch, and raises DependencyError
    naming the packages and the cause when it cannot."""

    def missing(self, names: Sequence[str]) -> list[str]: ...

    def install(self, names: Sequence[str], *, log: Log) -> None: ...


class PythonEnvs(Protocol):
    """Virtual environments for apps' pip requirements, one per set of requirements (every
    generation and app asking for the same set shares it), created with the system's
    site-packages visible so that apt's and ROS's Python stays importable.

    `unsatisfied` says which requirements the environment for that set would lack, read
    from distribution metadata (never by importing); `ensure` creates the environment if
    needed and installs what is unsatisfied (DependencyError naming the requirement and
    the tail of pip's output when it cannot); `collect` removes environments not in `keep`.
    """

    def location(self, requirements: Sequence[str]) -> Path: ...

    def ready(self, requirements: Sequence[str]) -> bool: ...

    def unsatisfied(self, requirements: Sequence[str]) -> list[str]: ...

    def ensure(self, requirements: Sequence[str], *, log: Log) -> Path: ...

    def collect(self, keep: set[Path]) -> None: ...


class Workspace(Protocol):
    """The ROS catkin workspace (`ros: {workspace, user}`): one immutable build per set of
    source commits, so that a rollback returns to a build that worked.

    A build lives in `space(key)`: `src/` (filled by the caller, before `build`, with the
    repositories exported at their commits), then `build/` and `devel/` from `catkin_make`
    run as the ROS user. `built(key)` is true only after a build succeeded. `link` points
    the workspace's own `src/<repo>` at a build's sources, where the field's scripts look.
    """

    root: Path

    def space(self, key: str) -> Path: ...

    def built(self, key: str) -> bool: ...

    def prepare(self, key: str) -> Path: ...

    def build(self, key: str, *, log: Log) -> None: ...

    def setup_script(self, key: str) -> Path: ...

    def link(self, key: str, repos: Sequence[str]) -> None: ...

    def collect(self, keep: set[str]) -> None: ...


@dataclass(frozen=True)
class DependencyPorts:
    """The three ports an app's dependencies are prepared through. A workspace is made
    for the path and user the desired state names (`ros:`), so it is a factory."""

    packages: Packages
    envs: PythonEnvs
    workspace: Callable[[Path, str], Workspace]


class Held(Protocol):
    """What an open gate holds through the cutover (the apps' update locks)."""

    def release(self) -> None: ...


class Gate(Protocol):
    """The update gates (adapters/gate.py): the cutover waits for a safe moment.

    `hold` re-checks until every gate is open or `wait` seconds have passed; open, it takes
    the apps' update locks and keeps them until `release`, so that no app begins a critical
    section mid-swap; still closed, it raises `Deferred` naming each closed gate. `states`
    is one look now, holding nothing (`lpam gates`)."""

    @property
    def unclaimed_free(self) -> bool:
        """A cutover of apps that claim nothing exclusive need not wait (`unclaimed: free`)."""
        ...

    def states(self) -> Sequence[GateState]: ...

    def hold(self, *, wait: float, progress: Callable[[str], None]) -> Held: ...


class Listener(Protocol):
    """The vehicle's CAN traffic, for a health check by CAN (adapters/gate.py)."""

    def heard(self, ids: Sequence[int], *, since: float, within: float) -> set[int]:
        """Which of `ids` appear on the bus in frames stamped at or after `since` (epoch
        seconds), listening at most `within` seconds; stops as soon as all were heard."""
        ...
