"""In-memory twins of the executor's ports, for fast tests of the real steps.

`MemoryStore` holds repositories as plain dicts (commit → folder → (tree, files));
`MemoryScripts` runs no process: it keeps a pessimistic model of the vehicle — which apps
are installed, which may be active on the CAN bus — and records a `violation` whenever a
script would give the bus a second app. A failing script is assumed to have done its harm
(a failed start.sh may have started things; a failed uninstall.sh left the app installed).
Both pass the same contract suite as the real adapters (tests/contract/).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from reconciler.base.blobs import blob_id
from reconciler.base.errors import (
    Deferred,
    DependencyError,
    GitError,
    RefNotFoundError,
    StepError,
    StoreDamagedError,
)
from reconciler.base.layout import Layout, slug
from reconciler.core.vehicle.policy import GateState
from reconciler.engine.execution.ports import (
    HEADS,
    READ_LIMIT,
    Fetched,
    Log,
    RemoteRefs,
    ambiguous,
)
from schemas.names import is_hex_commit

Folder = tuple[str, dict[str, str]]  # (tree hash, file name → text)


@dataclass
class MemoryStore:
    """Remotes (url → commit → folder → Folder) and local checkouts (key → url, head).
    With a `layout`, each checkout also has its (empty) folder, as observe looks for it.
    `damaged` (key → what is wrong) is a test's way to damage a checkout: its objects are
    unreadable, while its origin and HEAD (config and refs, in git) still read."""

    layout: Layout | None = None
    remotes: dict[str, dict[str, dict[str, Folder]]] = field(default_factory=dict)
    checkouts: dict[str, tuple[str, str | None]] = field(default_factory=dict)
    fetched: dict[str, set[str]] = field(default_factory=dict)
    fetches: int = 0
    damaged: dict[str, str] = field(default_factory=dict)
    aside: dict[str, tuple[str, str | None]] = field(default_factory=dict)
    advertised: dict[str, RemoteRefs] = field(default_factory=dict)  # url → its refs
    seen: dict[str, RemoteRefs] = field(default_factory=dict)  # key → the last fetch's
    brought: dict[str, str] = field(default_factory=dict)  # key → remote of a repointed one

    def origin_url(self, key: str) -> str | None:
        return self.checkouts[key][0] if key in self.checkouts else None

    def damage(self, key: str) -> str | None:
        return self.damaged.get(key) if key in self.checkouts else None

    def _readable(self, key: str) -> None:
        if self.damage(key) is not None:
            raise StoreDamagedError(key, self.damaged[key])

    def has_commit(self, key: str, commit: str) -> bool:
        self._readable(key)
        return commit in self.fetched.get(key, set())

    def head(self, key: str) -> str | None:
        return self.checkouts[key][1] if key in self.checkouts else None

    def local_edits(self, key: str) -> list[str]:
        self._readable(key)
        return []

    def renew(self, key: str, url: str) -> Path | None:
        if url not in self.remotes:
            raise GitError(f"{key}: cannot reach {url}")
        kept = self._keep_aside(key) if key in self.checkouts else None
        self.fetch(key, url)
        return kept

    def _keep_aside(self, key: str) -> Path:
        """The checkout forgotten, its folder (with a layout) moved where GitStore keeps it."""
        self.aside[key] = self.checkouts.pop(key)
        self.damaged.pop(key, None)
        self.fetched.pop(key, None)
        self.brought.pop(key, None)
        path = Path(f".{slug(key)}~damaged")
        if self.layout is not None:
            path = self.layout.repositories / path.name
            shutil.rmtree(path, ignore_errors=True)
            if self.layout.repository_dir(key).exists():
                self.layout.repository_dir(key).rename(path)
        return path

    def fetch(self, key: str, url: str, *, want: str | None = None) -> Fetched:
        """As GitStore: `want` (a commit `url` has) comes alone, added to what the same
        origin brought before; otherwise every commit. The refs kept are those whose
        commit the store holds."""
        if url not in self.remotes:
            raise GitError(f"{key}: cannot reach {url}")
        self.fetches += 1
        if self.layout is not None:
            self.layout.repository_dir(key).mkdir(parents=True, exist_ok=True)
        same = self.origin_url(key) == url
        shallow = want is not None and want in self.remotes[url]
        before = self.fetched.get(key, set()) if same else set()
        self.fetched[key] = before | {want} if shallow and want is not None \
            else set(self.remotes[url])
        self.checkouts[key] = (url, self.head(key))
        self.brought.pop(key, None)
        advertised = self.ls_remote(url)
        self.seen[key] = RemoteRefs(url=url, default_branch=advertised.default_branch,
                                    refs={name: commit for name, commit in advertised.refs.items()
                                          if commit in self.fetched[key]})
        return Fetched(url=url, shallow=shallow)

    def repoint(self, key: str, url: str) -> None:
        """See the `Store` port: no remote is asked; the twin goes on reading the files
        of the remote that brought its commits (`brought`)."""
        if key not in self.checkouts:
            raise GitError(f"{key} is not in the repository store")
        old, head = self.checkouts[key]
        self.brought.setdefault(key, old)
        self.checkouts[key] = (url, head)
        self.seen.pop(key, None)

    def fetch_objects(self, key: str, url: str, *, want: str | None = None) -> Fetched:
        """Commits of `url` for a plan to read, moving no checkout; a checkout of another
        origin keeps its origin (the twin reads files of its origin's commits only)."""
        if key not in self.checkouts or self.origin_url(key) == url:
            return self.fetch(key, url, want=want)
        if url not in self.remotes:
            raise GitError(f"{key}: cannot reach {url}")
        self.fetches += 1
        shallow = want is not None and want in self.remotes[url]
        self.fetched[key] |= {want} if shallow and want is not None else set(self.remotes[url])
        return Fetched(url=url, shallow=shallow)

    def ls_remote(self, url: str) -> RemoteRefs:
        if url not in self.remotes:
            raise GitError(f"cannot reach {url}")
        return self.advertised.get(url, RemoteRefs(url=url, refs={}, default_branch=None))

    def local_refs(self, key: str) -> RemoteRefs | None:
        """What the last fetch saw of the origin's branches and tags, without network."""
        if key not in self.checkouts:
            return None
        seen = self.seen.get(key)
        refs = {} if seen is None else dict(seen.refs)
        default = next((b for b in ("main", "master") if HEADS + b in refs), None)
        return RemoteRefs(url=self.checkouts[key][0], refs=refs, default_branch=default)

    def resolve_local(self, key: str, ref: str) -> str | None:
        """An abbreviated hash expanded against the commits already fetched."""
        ref = ref.lower()
        if not is_hex_commit(ref):
            return None
        self._readable(key)
        commits = sorted(c for c in self.fetched.get(key, set()) if c.startswith(ref))
        if len(commits) > 1:
            raise ambiguous(key, ref, commits)
        return commits[0] if commits else None

    def _folder(self, key: str, commit: str, folder: str) -> Folder | None:
        """`commit:folder` of the key's origin, once that commit was fetched."""
        url = self.brought.get(key) or self.origin_url(key)
        found = None if url is None else self.remotes[url].get(commit, {}).get(folder)
        return None if found is None or not self.has_commit(key, commit) else found

    def folder_tree(self, key: str, commit: str, folder: str) -> str | None:
        found = self._folder(key, commit, folder)
        return None if found is None else found[0]

    def location(self, key: str) -> Path:
        return self.layout.repository_dir(key) if self.layout is not None else Path(key)

    def checkout(self, key: str, commit: str) -> None:
        self._readable(key)
        if not self.has_commit(key, commit):
            raise RefNotFoundError(f"{key}: commit {commit} is not in the store")
        self.checkouts[key] = (self.checkouts[key][0], commit)

    def remove(self, key: str) -> None:
        if self.damage(key) is not None:
            self._keep_aside(key)
            return
        if self.layout is not None:
            shutil.rmtree(self.layout.repository_dir(key), ignore_errors=True)
        self.checkouts.pop(key, None)
        self.fetched.pop(key, None)
        self.brought.pop(key, None)

    def read_file(self, key: str, commit: str, path: str, *,
                  limit: int = READ_LIMIT) -> bytes | None:
        """A file of a folder (`folder/name`, a top-level file in folder ""); GitError when
        it is larger than `limit`, as the real store."""
        folder, _, name = path.rpartition("/")
        found = self._folder(key, commit, folder)
        if found is None or name not in found[1]:
            return None
        data = found[1][name].encode("utf-8")
        if len(data) > limit:
            raise GitError(f"{key}: '{path}' is {len(data)} bytes, over {limit}")
        return data

    def folder_files(self, key: str, commit: str, folder: str) -> list[str]:
        found = self._folder(key, commit, folder)
        return [] if found is None else sorted(n for n in found[1] if "/" not in n)

    def folder_blobs(self, key: str, commit: str, folder: str) -> dict[str, str] | None:
        found = self._folder(key, commit, folder)
        if found is None:
            return None
        return {name: blob_id(text.encode("utf-8")) for name, text in found[1].items()}

    def export_folder(self, key: str, commit: str, folder: str, dest: Path) -> str:
        self._readable(key)
        found = self._folder(key, commit, folder)
        if found is None:
            raise RefNotFoundError(f"{key}: there is no folder '{folder}' at commit {commit}")
        tree, files = found
        dest.mkdir(parents=True)
        for name, text in files.items():
            (dest / name).write_text(text)
            os.chmod(dest / name, 0o755)
        return tree


class Crash(BaseException):
    """lpam dying (SIGKILL, power cut) at a chosen script: not an LpamError, not caught."""


@dataclass
class MemoryScripts:
    """Script runs against a model of the vehicle; `calls` is the trace an operator reads."""

    runs_dir: Path
    calls: list[str] = field(default_factory=list)
    installed: set[str] = field(default_factory=set)
    active: set[str] = field(default_factory=set)
    violations: list[str] = field(default_factory=list)
    fail: set[str] = field(default_factory=set)  # "app:script" that exit 1 (once each)
    crash: Callable[[str], str | None] = lambda call: None  # "before" | "during" | "after"

    def run(
        self, app: str, app_dir: Path, script: str, params: dict[str, str], *,
        run: str, required: bool = False,
    ) -> bool:
        call = f"{app}:{script}"
        if not (app_dir / script).is_file():
            if required:
                raise StepError(f"{app}: {script} is missing from {app_dir}")
            return False
        when = self.crash(call)
        if when == "before":
            raise Crash(call)
        self.calls.append(call)
        self._effect(app, script)
        if when == "during":
            raise Crash(call)  # cut off: no exit code is ever written
        code = 1 if call in self.fail else 0
        self.fail.discard(call)
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        (self.runs_dir / f"{run}.exit").write_text(f"{code}\n")  # what the guard does
        if when == "after":
            raise Crash(call)
        if code:
            raise StepError(f"{app}: {script} failed with exit code {code}")
        return True

    def check(
        self, app: str, app_dir: Path, argv: list[str], params: dict[str, str], *,
        timeout: float,
    ) -> tuple[bool, str]:
        """A health check passes unless `app:check` is in `fail` (once)."""
        call = f"{app}:check"
        self.calls.append(call)
        if call in self.fail:
            self.fail.discard(call)
            return False, "exit code 1"
        return True, "exit code 0"

    def _effect(self, app: str, script: str) -> None:
        others = (self.installed | self.active) - {app}
        if script in ("install.sh", "start.sh") and others:
            self.violations.append(f"{app} {script} while {sorted(others)} on the vehicle")
        if script == "install.sh":
            self.installed.add(app)
        elif script == "start.sh":
            self.active.add(app)
        elif script == "stop.sh" and f"{app}:stop.sh" not in self.fail:
            self.active.discard(app)
        elif script == "uninstall.sh" and f"{app}:uninstall.sh" not in self.fail:
            self.installed.discard(app)


@dataclass
class MemoryPackages:
    """The `Packages` port as sets: `installed` names are present, `available` ones can be
    installed, `after_update` ones only once the package lists were updated (a car offline
    for weeks), anything else is not found."""

    installed: set[str] = field(default_factory=set)
    available: set[str] = field(default_factory=set)
    after_update: set[str] = field(default_factory=set)
    calls: list[list[str]] = field(default_factory=list)

    def missing(self, names: Sequence[str]) -> list[str]:
        return [name for name in names if name.split(":")[0] not in self.installed]

    def install(self, names: Sequence[str], *, log: Log) -> None:
        if not names:
            return
        for attempt in range(2):
            self.calls.append(["install", *names])
            unknown = [n for n in names if n.split(":")[0] not in self.available]
            if not unknown:
                self.installed.update(name.split(":")[0] for name in names)
                return
            if attempt == 0:
                self.calls.append(["update"])
                self.available |= self.after_update
        raise DependencyError(
            f"apt-get could not install {', '.join(names)}: E: Unable to locate package "
            f"{unknown[0]}", details=[f"E: Unable to locate package {unknown[0]}"])


class MemoryGate:
    """The update gates as a test sets them: `closed` lists the reasons of the closed gates
    at each check, in turn (the last stays); `hold` re-checks once per second of `wait`
    without sleeping, as the real gate re-checks while frames arrive."""

    def __init__(self, *closed: list[str], unclaimed_free: bool = False) -> None:
        self._checks = list(closed) or [[]]
        self.unclaimed_free = unclaimed_free
        self.holds = 0  # how many times the locks were taken
        self.releases = 0

    def _next(self) -> list[str]:
        return self._checks.pop(0) if len(self._checks) > 1 else self._checks[0]

    def states(self) -> list[GateState]:
        reasons = self._next()
        if not reasons:
            return [GateState("vehicle", True, "parked")]
        return [GateState("vehicle", False, why) for why in reasons]

    def hold(self, *, wait: float, progress: Callable[[str], None]) -> MemoryGate:
        for _ in range(int(wait) + 1):
            states = self.states()
            if all(s.open for s in states):
                self.holds += 1
                return self
            progress("waiting for the gates")
        raise Deferred("the update gates are closed: "
                       + "; ".join(s.describe() for s in states if not s.open),
                       gates=tuple(s.name for s in states if not s.open))

    def release(self) -> None:
        self.releases += 1
