"""What the status report is built from, read once: the state record, each installed
app's unit as its manager answers, the catalogs and app files as committed, the agent's
status, a local override, whether an apply in progress still lives (a deferral is the
record's last apply, reconciler/report/build.py), and the mode and owner of lpam's files
(reconciler/report/exposure.py names them).

All of the report's reading is here, so that reconciler/report/build.py decides from
values alone. The catalog and the app files (`service`, `description`…) are read from the
git objects of the recorded commit, never from the working tree: a repository may hold a
symbolic link (`service -> /etc/shadow`, or an app folder linking to `/etc`), and a
checkout may be edited, while a blob is exactly what was committed and a link in git is
never followed. It never loads the graph stack, and reads nothing it does not show.

What a repository holds is shown, so it is not trusted: a file too large is left out
rather than failing the whole answer. A repository whose copy in the store is damaged
keeps its listing, saying so, and the others are read as ever: status must answer most
when something is wrong.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from reconciler.base.errors import ConfigError, GitError, LpamError, StoreDamagedError
from reconciler.base.layout import Layout
from reconciler.engine.records import catalogs
from reconciler.engine.records.bluetooth import read_service
from reconciler.engine.records.state import read_agent_status, read_override, read_record
from reconciler.report.exposure import Files, Found, watched
from schemas.catalog import CATALOG_FILE, CatalogApp, with_folder_files
from schemas.report import Unreadable

if TYPE_CHECKING:
    from reconciler.base.unit import UnitState
    from schemas.agent import AgentStatus
    from schemas.bluetooth import BleService
    from schemas.override import LocalOverride
    from schemas.record import RepositoryRecord, StateRecord

# Imported inside functions: status reads committed files without dulwich (GitStore and the
# takeover check only when needed; test_imports.py); pwd/grp/lock readers are cheap.

SHOWN_FILES = ("description.txt", "service")  # the scripts are not shown, so not read


class Objects(Protocol):
    """What status needs of the repository store (adapters.git.GitStore): committed blobs."""

    def has_commit(self, key: str, commit: str) -> bool: ...

    def read_file(self, key: str, commit: str, path: str) -> bytes | None: ...

    def damage(self, key: str) -> str | None: ...

    def location(self, key: str) -> Path:
        """The key's checkout (parsed catalogs are kept in its .git)."""
        ...


@dataclass(frozen=True)
class Listing:
    """A repository's apps as committed (each with its descriptive files, read at the
    commit it is shown from: an installed app's own), or a note about the repository."""

    repository: str
    ref: str
    commit: str  # abbreviated, as shown
    apps: tuple[CatalogApp, ...] = ()
    note: str | None = None
    damage: str | None = None  # the store's copy is damaged: what is wrong


@dataclass(frozen=True)
class Seen:
    """Everything the report says, as read. `alive`: the apply in progress (if any) still
    has its process and holds the lock."""

    record: StateRecord
    listings: tuple[Listing, ...] = ()
    lives: Mapping[str, UnitState] = field(default_factory=dict)
    manager: str | None = None
    alive: bool = False
    agent: AgentStatus | Unreadable | None = None
    override: LocalOverride | Unreadable | None = None
    adopt: Mapping[str, str] = field(default_factory=dict)  # desired app -> LPAM's app
    decided: bool = True  # whether what an apply does with each app LPAM installed is known
    files: Files | None = None  # lpam's files' modes and owners; None: not read
    bluetooth: BleService | None = None  # the running `lpam ble`: who may change the car


def gather(layout: Layout, *, store: Objects | None = None,
           state: Callable[[str], UnitState] | None = None, manager: str | None = None,
           record: StateRecord | None = None, listed: bool = True) -> Seen:
    """Read what the report needs, the record once (an apply may rewrite it meanwhile).
    `state` asks the service manager (`manager`) about a unit; `record` replaces the one
    on disk (the shim lists the desired state's repositories, not the recorded ones).
    `listed` False: no repository's catalog is read (the published status and the phone's
    summary show the installed apps only, and an agent publishes every few minutes)."""
    if store is None and listed:  # the committed files, read without dulwich's import
        from reconciler.adapters.objectfiles import ObjectFiles

        store = ObjectFiles(layout)
    if record is None:
        record = read_record(layout)
    lives = {} if state is None else \
        {a.name: state(a.service) for a in record.apps if a.service is not None}
    found = () if store is None or not listed else tuple(listings(record, store))
    adopt, decided = taken_over(layout, record)
    return Seen(record=record, listings=found, lives=lives,
                manager=manager, alive=_alive(layout, record), agent=_agent(layout),
                override=_override(layout), adopt=adopt, decided=decided,
                files=files(layout, record), bluetooth=read_service(layout))


def taken_over(layout: Layout, record: StateRecord) -> tuple[dict[str, str], bool]:
    """What plan and apply do with each app LPAM installed, asked as they ask it
    (engine/observe/adoption.py, the observation behind `Observed.adopt`), offline: the
    desired apps it is as it is (desired app -> LPAM's app), and whether that is known —
    not before the store holds the desired commits (the first `lpam plan` fetches them).
    Read only on a car LPAM left an app on, from the default desired state's file."""
    if not any(s.folder is not None for s in record.strays):
        return {}, True
    path = layout.desired_state
    if not path.exists():
        return {}, False
    from reconciler.adapters.git import GitStore
    from reconciler.core.documents import load_desired
    from reconciler.engine.observe.adoption import adoptable
    from reconciler.engine.observe.targets import Fetch, resolve

    store = GitStore(layout)
    try:
        targets = resolve(load_desired(path), base_dir=path.resolve().parent, store=store,
                          fetch=Fetch.OFFLINE, root=layout.root)
        adopt = adoptable(layout, store, record, targets)
    except LpamError:  # status answers; the plan says what is wrong
        return {}, False
    known = all(a.tree is not None for a in targets.apps)  # each folder read at its commit
    return adopt, known


def listings(record: StateRecord, store: Objects) -> list[Listing]:
    """Every recorded repository's apps at its recorded commit, then each installed app
    its repository's catalog does not list (an apply that moved the repository was cut
    off, or the catalog changed): it may be the one that holds the CAN hardware."""
    found = [_listing(record, repo, store) for repo in record.repositories]
    shown = {(x.repository, a.name) for x in found for a in x.apps}
    for app in record.apps:
        if (app.repository, app.name) in shown:
            continue
        repo = record.repository(app.repository)
        ref = "-" if repo is None else repo.ref or "(default)"
        described = _described(store, app.repository, app.commit, app.path,
                                CatalogApp(name=app.name, path=app.path))
        found.append(Listing(app.repository, ref, app.commit[:12], apps=(described,)))
    return found


def _listing(record: StateRecord, repo: RepositoryRecord, store: Objects) -> Listing:
    ref, short = repo.ref or "(default)", repo.commit[:12]
    try:
        present = store.has_commit(repo.key, repo.commit)
    except StoreDamagedError as exc:
        return Listing(repo.key, ref, short, damage=exc.damage)
    if not present:  # a lost pack or index hides commits without any read failing
        damage = store.damage(repo.key)
        note = "(commit missing from the repository store)" if damage is None else None
        return Listing(repo.key, ref, short, note=note, damage=damage)
    try:
        data = store.read_file(repo.key, repo.commit, CATALOG_FILE)
    except GitError as exc:
        return Listing(repo.key, ref, short, note=f"(catalog unreadable: {exc.message})")
    if data is None:
        return Listing(repo.key, ref, short, note="(no libpanda-apps.yaml)")
    label = Path(f"{repo.key}@{short}/{CATALOG_FILE}")
    try:
        catalog = catalogs.parsed(store.location(repo.key), label, data)
    except ConfigError as exc:
        return Listing(repo.key, ref, short, note=f"(catalog unreadable: {exc.message})")
    apps = []
    for app in catalog.apps:
        mine = record.installed(app.name)
        if mine is not None and mine.repository == repo.key:  # its files as installed
            apps.append(_described(store, repo.key, mine.commit, mine.path, app))
        else:
            apps.append(_described(store, repo.key, repo.commit, app.path, app))
    return Listing(repo.key, ref, short, apps=tuple(apps))


def _described(store: Objects, key: str, commit: str, folder: str,
               app: CatalogApp) -> CatalogApp:
    """The app with its descriptive files as committed (regular blobs only: links are not
    read). A file too large to be a description is left out: the rest still shows."""
    files = {}
    for name in SHOWN_FILES:
        try:
            data = store.read_file(key, commit, f"{folder.rstrip('/')}/{name}")
        except GitError:
            continue
        if data is not None:
            files[name] = data
    return with_folder_files(app, files)


def _alive(layout: Layout, record: StateRecord) -> bool:
    """An apply `in progress` lives while its process does and holds the lock; one whose
    process is gone was cut off (a kill, a power cut) — even while a script it started
    still holds the lock (that script's note names the dead apply's pid)."""
    last = record.last_apply
    if last is None or last.result != "in progress" or last.pid is None:
        return False
    from reconciler.base.process import alive
    from reconciler.engine.execution.lock import Holding, holder

    note = holder(layout)
    return note is not None and alive(last.pid) and Holding.of(note).pid in (None, last.pid)


def files(layout: Layout, record: StateRecord) -> Files:
    """The mode and owner of each path exposure.watched names: one stat each. A path that
    does not exist is left out (there is nothing to change yet, and its directory is
    checked), and so is one this user may not stat."""
    found = []
    for item in watched(layout, record):
        try:
            info = os.stat(item.path)
        except OSError:
            continue
        found.append(Found(item.path, item.what, info.st_mode, info.st_uid, info.st_gid))
    user = os.geteuid()
    return Files(found=tuple(found), user=user,
                 users={uid: _user(uid) for uid in {user, *(f.uid for f in found)}},
                 groups={gid: _group(gid) for gid in {f.gid for f in found}})


def _user(uid: int) -> str | None:
    import pwd

    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return None


def _group(gid: int) -> str | None:
    import grp

    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return None


def _override(layout: Layout) -> LocalOverride | Unreadable | None:
    """The local override in force (reconciler/workflow/override.py)."""
    try:
        return read_override(layout)
    except LpamError as exc:
        return Unreadable(error=exc.message)


def _agent(layout: Layout) -> AgentStatus | Unreadable | None:
    """What the agent's passes recorded (status.json); None on a machine with no agent."""
    try:
        return read_agent_status(layout)
    except LpamError as exc:
        return Unreadable(error=exc.message)
