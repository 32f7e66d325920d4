"""Resolve the desired state to commits: which commit each repository should be at, and
where the desired app comes from.

This is the only probe that may use the network, and only when it must: a ref that is a
commit hash already in the store is resolved locally (a pinned no-op plan opens no
connection); a branch or tag is looked up with one ls-remote. Commits not yet in the store
are then fetched, so that the plan reads the catalog and app folder it will install and is
exact — how depends on the `Fetch` mode:

- `CHECKOUT` (apply): `store.fetch`, which may re-clone a repository whose URL changed;
- `OBJECTS` (plan): `store.fetch_objects`, which adds commits to the object database and
  never moves a checkout, so a plan changes nothing anyone could see;
- `OFFLINE` (`plan --offline`): no network at all; branches and tags resolve to what the
  last fetch saw, and what is not local stays "known after fetch".

Before a repository is read, its copy in the store is checked (`store.damage`): the store
is a cache, so apply (`CHECKOUT`) fetches a damaged copy anew and says so, keeping the old
one aside, while a plan, which must change nothing, refuses it, naming the repository and
what the next apply does.
"""

from __future__ import annotations

import getpass
import pwd
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from reconciler.base.errors import CatalogError, GitError, RefNotFoundError, StoreDamagedError
from reconciler.base.layout import Layout
from reconciler.base.unit import check_unit_name
from reconciler.core.planning.model import (
    LIFECYCLE_SCRIPTS,
    UNKNOWN,
    AppTarget,
    Deps,
    HealthTarget,
    RepoTarget,
    RosSource,
    Targets,
    WorkspaceTarget,
    short,
)
from reconciler.engine.records import catalogs, damage
from schemas.catalog import (
    CATALOG_FILE,
    SERVICE_PREFIX,
    Catalog,
    CatalogApp,
    RosRepository,
)
from schemas.desired import AppSpec, DesiredState
from schemas.names import is_hex_commit, redact
from schemas.service import DEFAULT_HEALTH_TIMEOUT, DEFAULT_SETTLE_SECONDS, Health

if TYPE_CHECKING:
    from reconciler.engine.execution.ports import Fetched, Resolving

FETCH_WORKERS = 4
ROS_KEY_PREFIX = "@ros/"  # store keys of ROS repositories: never an app repository's key
_In = TypeVar("_In")
_Out = TypeVar("_Out")


class Fetch(Enum):
    """How far resolving may go to make the plan exact (see the module docstring)."""

    CHECKOUT = "checkout"
    OBJECTS = "objects"
    OFFLINE = "offline"


Notice = Callable[[str], None]
"""Where resolving tells the user what it did beyond resolving (a damaged copy fetched anew)."""


def resolve(
    desired: DesiredState, *, base_dir: Path, store: Resolving, fetch: Fetch,
    default_user: str | None = None, root: Path = Path("/"), notice: Notice = lambda _: None,
) -> Targets:
    """Desired state → Targets; raises before any change if a ref does not exist.
    `default_user` runs a scriptless app that names no `user:` (the libpanda user) and
    owns the ROS workspace; `root` is lpam's --root, under which the workspace lies."""
    repos = _parallel(lambda s: _resolve_ref(s.key, desired.mirrored(s.source(base_dir)),
                                             s.ref, store, fetch, notice),
                      desired.repositories, fetch)
    workspace = workspace_target(desired, root, default_user)
    bare: set[str] = set()  # repositories with no catalog, as reading them found
    apps = [_resolve_app(desired, spec, repos, store, default_user, fetch, workspace, notice,
                         bare) for spec in desired.apps]
    repos = [replace(r, no_catalog=True) if r.key in bare else r for r in repos]
    return Targets(tuple(repos), apps=tuple(apps))


def workspace_target(desired: DesiredState, root: Path,
                     default_user: str | None) -> WorkspaceTarget:
    """`ros:` with its defaults: the libpanda user (else lpam's own) and their ~/catkin_ws,
    where the field's scripts look."""
    user = desired.ros.user or default_user or getpass.getuser()
    layout = Layout(root)
    path = layout.home(user) / "catkin_ws" if desired.ros.workspace is None \
        else layout.under(desired.ros.workspace)
    return WorkspaceTarget(path=str(path), user=user)


def _parallel(work: Callable[[_In], _Out], items: Sequence[_In], fetch: Fetch) -> list[_Out]:
    """`work` on each item, several at once when each may wait on the network."""
    if len(items) > 1 and fetch is not Fetch.OFFLINE:
        with ThreadPoolExecutor(max_workers=min(FETCH_WORKERS, len(items))) as pool:
            return list(pool.map(work, items))
    return [work(item) for item in items]


def _bring(store: Resolving, key: str, url: str, fetch: Fetch,
           want: str | None) -> Fetched | None:
    """Fetch what resolving `key` needs: the commit `want` alone (a full hash), else
    every branch and tag. What came (`fetched_note` tells the user)."""
    if fetch is Fetch.OFFLINE:
        return None
    if fetch is Fetch.CHECKOUT:
        return store.fetch(key, url, want=want)
    return store.fetch_objects(key, url, want=want)


def fetched(targets: Targets) -> list[RepoTarget]:
    """The repositories (ROS sources included) resolving fetched something for."""
    return [r for r in (*targets.repositories,
                        *(s.repo for a in targets.apps for s in a.deps.ros))
            if r.fetched is not None]


def fetched_note(targets: Targets) -> str | None:
    """What resolving fetched, in one line: on a phone's hotspot or a metered link, the
    bytes are what an update costs. None when nothing was fetched."""
    repos = fetched(targets)
    if not repos:
        return None
    alone = all(r.fetched_alone for r in repos)
    total = _size(sum(r.fetched or 0 for r in repos))
    if len(repos) == 1:
        what = "the commit alone" if alone else "with its history"
        return f"fetched {repos[0].key} from {redact(repos[0].url)}: {total} ({what})"
    what = "each commit alone" if alone else "some with their history"
    return f"fetched {len(repos)} repositories: {total} in all ({what})"


def _size(count: int) -> str:
    """Bytes as a person reads them: 61.3 kB, 3.7 MB."""
    for unit, scale in (("MB", 1e6), ("kB", 1e3)):
        if count >= scale:
            return f"{count / scale:.1f} {unit}"
    return f"{count} bytes"


def sound_copy(store: Resolving, key: str, url: str, *, renew: bool, notice: Notice) -> None:
    """Make sure the key's copy in the store is sound before anything reads it: a damaged
    copy is fetched anew from `url` when `renew` (apply), else refused (a plan changes
    nothing); see reconciler/engine/records/damage.py."""
    found = store.damage(key)
    if found is None:
        return
    if not renew:
        raise damage.refused(key, url, found, store.location(key))
    notice(damage.renew(store, key, url, found))


def _resolve_ref(key: str, url: str, ref: str | None, store: Resolving,
                 fetch: Fetch, notice: Notice) -> RepoTarget:
    """The commit `ref` names in the repository at `url` (stored as `key`): a hash stays,
    a branch or tag follows its tip, none follows the default branch."""
    sound_copy(store, key, url, renew=fetch is Fetch.CHECKOUT, notice=notice)
    commit: str | None = None
    if ref is not None and is_hex_commit(ref):
        # A commit hash names the same content whichever remote brought it.
        commit = store.resolve_local(key, ref)
        if commit is not None:
            return RepoTarget(key=key, url=url, ref=ref, commit=commit, in_store=True)
        if fetch is not Fetch.OFFLINE:
            want = ref.lower() if len(ref) == 40 else None
            fetched = _bring(store, key, url, fetch, want)
            commit = store.resolve_local(key, ref)
            if commit is None:
                raise RefNotFoundError(
                    f"commit {ref} not found in {redact(url)}",
                    hint="check the hash (is it pushed?); nothing on the machine was changed",
                )
            return _fetched(RepoTarget(key=key, url=url, ref=ref, commit=commit), fetched)
        elif commit is None and len(ref) == 40:
            commit = ref
    elif fetch is Fetch.OFFLINE:
        local = store.local_refs(key) if store.origin_url(key) == url else None
        commit = local.resolve(ref) if local is not None else None
        return RepoTarget(key=key, url=url, ref=ref, commit=commit, as_of_last_fetch=True)
    else:
        remote = store.ls_remote(url)
        commit = remote.resolve(ref)
        if commit is None:
            heads, tags = (sorted(r.removeprefix(kind) for r in remote.refs
                                  if r.startswith(kind)) for kind in ("refs/heads/", "refs/tags/"))
            what = f"ref {ref!r}" if ref else "a default branch"
            raise RefNotFoundError(
                f"{what} not found in {redact(url)} (branches: {', '.join(heads) or 'none'}; "
                f"tags: {', '.join(tags) or 'none'})",
                hint="fix `ref:` in the desired state; nothing on the machine was changed",
            )
        if not store.has_commit(key, commit) or \
                (fetch is Fetch.CHECKOUT and store.origin_url(key) != url):
            fetched = _bring(store, key, url, fetch, commit)
            return _fetched(RepoTarget(key=key, url=url, ref=ref, commit=commit), fetched)
    return RepoTarget(key=key, url=url, ref=ref, commit=commit)


def _fetched(target: RepoTarget, done: Fetched | None) -> RepoTarget:
    if done is None:
        return target
    return replace(target, fetched=done.bytes, fetched_alone=done.shallow)


NO_CATALOG = Catalog()  # what a commit without libpanda-apps.yaml offers: nothing


def _catalog(store: Resolving, repo: RepoTarget) -> Catalog | None:
    """The repository's app catalog at its target commit; None when not fetched yet,
    NO_CATALOG when the commit has no libpanda-apps.yaml. A commit's content is the same
    whichever remote brought it, so the origin of the checkout does not matter here."""
    if repo.commit is None or not store.has_commit(repo.key, repo.commit):
        return None
    data = store.read_file(repo.key, repo.commit, CATALOG_FILE)
    if data is None:
        return NO_CATALOG
    label = Path(f"{repo.key}@{short(repo.commit)}/{CATALOG_FILE}")
    return catalogs.parsed(store.location(repo.key), label, data)


def _resolve_app(
    desired: DesiredState, spec: AppSpec, repos: list[RepoTarget], store: Resolving,
    default_user: str | None, fetch: Fetch, workspace: WorkspaceTarget, notice: Notice,
    bare_keys: set[str],
) -> AppTarget:
    candidates = _candidates(desired, spec, repos)
    found: list[tuple[RepoTarget, CatalogApp]] = []
    unknown: list[RepoTarget] = []
    offered: list[str] = []
    bare: list[str] = []
    for repo in candidates:
        catalog = _catalog(store, repo)
        if catalog is None:
            unknown.append(repo)
            continue
        if catalog is NO_CATALOG:
            bare.append(f"{repo.key}@{short(repo.commit)}")
            bare_keys.add(repo.key)
        app = catalog.app(spec.name)
        offered += [f"{a.name} ({repo.key})" for a in catalog.apps]
        if app is not None:
            found.append((repo, app))
    if len(found) > 1:
        raise CatalogError(
            f"app {spec.name} is offered by {' and '.join(r.key for r, _ in found)}",
            hint="say which one with `app: {name: …, repository: owner/name}`",
        )
    if found:
        repo, entry = found[0]
        path = entry.path
        assert repo.commit is not None
        tree = store.folder_tree(repo.key, repo.commit, path)
        if tree is None:
            raise CatalogError(
                f"{repo.key}@{short(repo.commit)}: the catalog lists app {spec.name} in folder "
                f"{path!r}, but that folder does not exist",
                hint="fix the repository's libpanda-apps.yaml or pin another commit",
            )
        target = _app_target(spec, repo, entry, tree, store, default_user)
        return replace(target, deps=_deps(desired, entry, store, fetch, workspace, notice))
    if unknown:
        repo = unknown[0] if len(unknown) == 1 else RepoTarget(UNKNOWN, "", None, None)
        return AppTarget(name=spec.name, repository=repo.key, commit=repo.commit, path=None,
                         tree=None, params=dict(spec.params))
    missing = f"; {', '.join(bare)} {'has' if len(bare) == 1 else 'have'} no " \
        f"{CATALOG_FILE} (an app repository lists its apps there)" if bare else ""
    raise CatalogError(
        f"app {spec.name} is not in the catalog of any desired repository "
        f"(available: {', '.join(offered) or 'none'}){missing}",
        hint="check the app name, or add the repository that offers it" if not bare else
        f"add {CATALOG_FILE} to that repository, or add the repository that offers the app",
    )


def _candidates(desired: DesiredState, spec: AppSpec, repos: list[RepoTarget]
                ) -> list[RepoTarget]:
    """The repositories whose catalogs may offer the app: the one `app.repository` names,
    else every desired repository."""
    if spec.repository is None:
        return repos
    wanted = desired.repository(spec.repository)
    if wanted is None:
        raise CatalogError(
            f"app.repository {spec.repository!r} is not one of the desired repositories "
            f"({', '.join(r.key for r in repos) or 'none'})",
            hint="use the key (owner/name) or URL of a listed repository",
        )
    return [r for r in repos if r.key == wanted.key]


def _app_target(
    spec: AppSpec, repo: RepoTarget, entry: CatalogApp, tree: str, store: Resolving,
    default_user: str | None,
) -> AppTarget:
    """The desired app as it will run: how (scripts or a unit lpam writes), as whom, and
    when it counts as healthy (the desired state's `health` over the catalog's)."""
    assert repo.commit is not None
    scriptless = entry.command is not None or entry.launch is not None
    service = None
    if not scriptless:
        data = store.read_file(repo.key, repo.commit, f"{entry.path}/service", limit=4096)
        text = data.decode("utf-8", "replace").strip() if data is not None else ""
        if text:
            try:
                service = check_unit_name(text.split()[0])
            except ValueError as exc:
                raise CatalogError(
                    f"{repo.key}@{short(repo.commit)}: app {spec.name}: its `service` file: "
                    f"{exc}", hint="fix the app's `service` file or pin another commit",
                ) from None
    # which scripts it has, for the plan's words (a script that is a link is not counted)
    scripts = None if scriptless else LIFECYCLE_SCRIPTS.intersection(
        store.folder_files(repo.key, repo.commit, entry.path))
    user = spec.user or default_user if scriptless else None
    if user is not None:
        _check_user(spec.name, user)
    health = (spec.health or Health()).over(entry.health)
    claims = entry.resources | ({SERVICE_PREFIX + service} if service else frozenset())
    return AppTarget(
        name=spec.name, repository=repo.key, commit=repo.commit, path=entry.path, tree=tree,
        params=dict(spec.params), service=service,
        command=tuple(entry.command) if entry.command is not None else None,
        launch=entry.launch, user=user, resources=claims, scripts=scripts,
        data=tuple(spec.data if spec.data is not None else entry.data),
        health=HealthTarget(
            settle_seconds=DEFAULT_SETTLE_SECONDS if health.settle_seconds is None
            else health.settle_seconds,
            command=tuple(health.command) if health.command is not None else None,
            timeout_seconds=DEFAULT_HEALTH_TIMEOUT if health.timeout_seconds is None
            else health.timeout_seconds,
            can_ids=tuple(health.can.ids) if health.can is not None else (),
            can_within=health.can.within_seconds if health.can is not None else 10.0,
        ),
    )


def _deps(desired: DesiredState, entry: CatalogApp, store: Resolving, fetch: Fetch,
          workspace: WorkspaceTarget, notice: Notice) -> Deps:
    """The app's apt packages, pip requirements and ROS repositories, the latter resolved
    to commits by the same rules as app repositories (through the desired mirrors)."""

    def ros(source: RosRepository) -> RosSource:
        key = f"{ROS_KEY_PREFIX}{source.owner}/{source.repo}"
        try:
            found = _resolve_ref(key, desired.mirrored(source.source), source.ref, store, fetch,
                                 notice)
        except StoreDamagedError:  # names the ROS repository's key (@ros/owner/repo) itself
            raise
        except GitError as exc:
            raise type(exc)(f"app {entry.name}: ROS repository {source.owner}/{source.repo}: "
                            f"{exc.message}", hint=exc.hint) from None
        return RosSource(name=source.repo, repo=found)

    return Deps(apt=tuple(entry.apt), pip=tuple(entry.pip3),
                ros=tuple(_parallel(ros, entry.ros_repositories, fetch)),
                workspace=workspace if entry.ros_repositories else None)


def _check_user(app: str, user: str) -> None:
    try:
        pwd.getpwnam(user)
    except KeyError:
        raise CatalogError(
            f"app {app}: user {user!r} does not exist on this machine",
            hint="create the user, or set `app.user:` in the desired state to one that exists",
        ) from None
