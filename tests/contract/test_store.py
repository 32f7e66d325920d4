"""One contract for every repository store: the real GitStore (dulwich, a real git daemon
on 127.0.0.1) and the in-memory MemoryStore the property tests drive the executor with.

What the executor relies on is written here once; a twin that drifts from the real
store fails the same test the real store passes, so a property proven with the twin is
a property of the steps, not of a convenient fake.
"""

from __future__ import annotations

import stat
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from reconciler.adapters.git import GitStore
from reconciler.adapters.memory import MemoryStore
from reconciler.base.errors import GitError, RefNotFoundError, StoreDamagedError
from reconciler.base.layout import Layout
from reconciler.engine.execution.ports import RemoteRefs, Resolving
from tests.gitserver import GitDaemon, RepoBuilder

KEY = "apps"


@dataclass
class Remote:
    """What the remote holds: two commits of one app folder, with their tree hashes."""

    url: str
    first: str
    second: str
    trees: dict[str, str]  # commit → tree hash of alpha/
    files: dict[str, dict[str, str]]  # commit → file name → text
    branch: str = "main"  # tests.gitserver makes every repository's default branch main


def build(repo: RepoBuilder, url: str) -> Remote:
    files = {"run.sh": "echo one\n"}
    repo.write("alpha/run.sh", files["run.sh"], executable=True)
    first = repo.commit("one")
    second = repo.commit("two", {"alpha/run.sh": "echo two\n"})
    repo.tag("v1", first, message="the first")  # annotated: advertised peeled
    repo.push()
    trees = {c: repo.rev(f"{c}:alpha") for c in (first, second)}
    return Remote(url, first, second, trees,
                  {first: files, second: {"run.sh": "echo two\n"}})


def memory_store(layout: Layout, remote: Remote) -> MemoryStore:
    folders = {c: {"alpha": (remote.trees[c], remote.files[c])} for c in remote.trees}
    refs = {f"refs/heads/{remote.branch}": remote.second, "refs/tags/v1": remote.first}
    return MemoryStore(layout=layout, remotes={remote.url: folders},
                       advertised={remote.url: RemoteRefs(remote.url, refs, remote.branch)})


def git_store(layout: Layout, remote: Remote) -> GitStore:
    return GitStore(layout, timeout=10)


@pytest.fixture(params=[git_store, memory_store], ids=["git", "memory"])
def world(
    request: pytest.FixtureRequest, tmp_path: Path, git_daemon: GitDaemon,
    make_repo: Callable[[str], RepoBuilder],
) -> Iterator[tuple[Resolving, Remote, Layout]]:
    remote = build(make_repo("apps.git"), git_daemon.url("apps.git"))
    layout = Layout(tmp_path / "root")
    factory: Callable[[Layout, Remote], Resolving] = request.param
    yield factory(layout, remote), remote, layout


def test_fetch_brings_every_commit_and_records_the_origin(
    world: tuple[Resolving, Remote, Layout],
) -> None:
    store, remote, _ = world
    assert store.origin_url(KEY) is None and not store.has_commit(KEY, remote.first)
    store.fetch(KEY, remote.url)
    assert store.origin_url(KEY) == remote.url
    assert store.has_commit(KEY, remote.first) and store.has_commit(KEY, remote.second)
    assert not store.has_commit(KEY, "0" * 40)
    assert store.local_edits(KEY) == []


def test_checkout_moves_head_and_refuses_unknown_commits(
    world: tuple[Resolving, Remote, Layout],
) -> None:
    store, remote, _ = world
    store.fetch(KEY, remote.url)
    store.checkout(KEY, remote.first)
    assert store.head(KEY) == remote.first
    store.checkout(KEY, remote.second)
    assert store.head(KEY) == remote.second
    with pytest.raises(RefNotFoundError):
        store.checkout(KEY, "1" * 40)
    assert store.head(KEY) == remote.second


def test_export_copies_the_folder_at_a_commit_with_its_tree_hash(
    world: tuple[Resolving, Remote, Layout], tmp_path: Path,
) -> None:
    store, remote, _ = world
    store.fetch(KEY, remote.url)
    dest = tmp_path / "gen"
    assert store.export_folder(KEY, remote.first, "alpha", dest) == remote.trees[remote.first]
    assert (dest / "run.sh").read_text() == "echo one\n"
    assert (dest / "run.sh").stat().st_mode & stat.S_IXUSR
    with pytest.raises(RefNotFoundError):
        store.export_folder(KEY, remote.first, "nowhere", tmp_path / "other")
    assert not (tmp_path / "other").exists()


def test_an_unreachable_remote_is_a_git_error_and_changes_nothing(
    world: tuple[Resolving, Remote, Layout],
) -> None:
    store, remote, _ = world
    store.fetch(KEY, remote.url)
    store.checkout(KEY, remote.first)
    with pytest.raises(GitError):
        store.fetch(KEY, remote.url.replace("apps.git", "missing.git"))
    assert store.origin_url(KEY) == remote.url and store.head(KEY) == remote.first


def test_repoint_needs_no_remote_and_forgets_what_the_old_one_advertised(
    world: tuple[Resolving, Remote, Layout], tmp_path: Path,
) -> None:
    """A pinned repository moved to another URL: the commits it holds stay readable, the
    new URL is its origin without the network, and the old origin's branches and tags are
    not read as the new one's (an offline plan would follow them)."""
    store, remote, _ = world
    store.fetch(KEY, remote.url)
    store.checkout(KEY, remote.first)
    unreachable = remote.url.replace("apps.git", "moved.git")
    store.repoint(KEY, unreachable)
    assert store.origin_url(KEY) == unreachable and store.head(KEY) == remote.first
    assert store.has_commit(KEY, remote.second)
    assert store.folder_tree(KEY, remote.second, "alpha") == remote.trees[remote.second]
    assert store.export_folder(KEY, remote.second, "alpha", tmp_path / "gen") == \
        remote.trees[remote.second]
    seen = store.local_refs(KEY)
    assert seen is not None and seen.resolve("main") is None and seen.resolve("v1") is None
    store.checkout(KEY, remote.second)
    assert store.head(KEY) == remote.second
    store.fetch(KEY, remote.url)  # back at the old URL: fetched anew, its refs again
    seen = store.local_refs(KEY)
    assert seen is not None and seen.resolve("main") == remote.second


def test_remove_forgets_the_checkout(world: tuple[Resolving, Remote, Layout]) -> None:
    store, remote, layout = world
    store.fetch(KEY, remote.url)
    store.checkout(KEY, remote.first)
    store.remove(KEY)
    assert store.origin_url(KEY) is None and store.head(KEY) is None
    assert not store.has_commit(KEY, remote.first)
    assert not layout.repository_dir(KEY).exists()
    store.remove(KEY)  # removing what is gone is not an error


def test_folder_blobs_name_each_file_by_its_content(
    world: tuple[Resolving, Remote, Layout], tmp_path: Path,
) -> None:
    """What a copy of the folder on disk is compared with when an app LPAM installed is
    adopted: each file's git blob id, whatever its mode."""
    from reconciler.base.blobs import blob_id

    store, remote, _ = world
    store.fetch(KEY, remote.url)
    assert store.folder_blobs(KEY, remote.first, "alpha") == {
        "run.sh": blob_id(b"echo one\n")}
    assert store.folder_blobs(KEY, remote.second, "alpha") == {
        "run.sh": blob_id(b"echo two\n")}
    assert store.folder_blobs(KEY, remote.first, "nowhere") is None


def damage(store: Resolving, layout: Layout) -> None:
    """Damage the checkout as a power cut or a failing SD card does: the real store's packs
    cut in half, the twin told so."""
    if isinstance(store, MemoryStore):
        store.damaged[KEY] = "pack cut in half"
        return
    packs = list((layout.repository_dir(KEY) / ".git" / "objects" / "pack").glob("*.pack"))
    assert packs
    for pack in packs:
        pack.chmod(0o644)
        with pack.open("r+b") as file:
            file.truncate(pack.stat().st_size // 2)


def test_a_damaged_checkout_is_named_and_never_read(
    world: tuple[Resolving, Remote, Layout], tmp_path: Path,
) -> None:
    store, remote, layout = world
    store.fetch(KEY, remote.url)
    store.checkout(KEY, remote.first)
    assert store.damage(KEY) is None and store.damage("absent") is None
    damage(store, layout)
    assert store.damage(KEY)
    reads: list[Callable[[], object]] = [
        lambda: store.has_commit(KEY, remote.first),
        lambda: store.checkout(KEY, remote.second),
        lambda: store.export_folder(KEY, remote.first, "alpha", tmp_path / "gen"),
        lambda: store.local_edits(KEY),
    ]
    for read in reads:
        with pytest.raises(StoreDamagedError) as info:
            read()
        assert info.value.key == KEY and f"repository {KEY}:" in info.value.message
    assert not (tmp_path / "gen").exists()
    assert store.origin_url(KEY) == remote.url  # its config and refs still read


def test_renew_fetches_afresh_and_keeps_the_damaged_copy_aside(
    world: tuple[Resolving, Remote, Layout], tmp_path: Path,
) -> None:
    store, remote, layout = world
    store.fetch(KEY, remote.url)
    store.checkout(KEY, remote.first)
    damage(store, layout)
    aside = store.renew(KEY, remote.url)
    assert aside is not None and aside.exists() and aside.parent == layout.repositories
    assert store.damage(KEY) is None and store.origin_url(KEY) == remote.url
    assert store.has_commit(KEY, remote.first) and store.has_commit(KEY, remote.second)
    assert store.head(KEY) is None  # a fresh clone: the next checkout puts HEAD back
    store.checkout(KEY, remote.first)
    assert store.export_folder(KEY, remote.first, "alpha", tmp_path / "gen") == \
        remote.trees[remote.first]
    assert store.renew("other", remote.url) is None  # nothing there: a plain clone


def test_renew_without_the_remote_moves_nothing(world: tuple[Resolving, Remote, Layout]) -> None:
    store, remote, layout = world
    store.fetch(KEY, remote.url)
    damage(store, layout)
    with pytest.raises(GitError):
        store.renew(KEY, remote.url.replace("apps.git", "missing.git"))
    assert store.damage(KEY) and store.origin_url(KEY) == remote.url
    assert not list(layout.repositories.glob("*~damaged"))


def test_remove_keeps_a_damaged_copy_aside(world: tuple[Resolving, Remote, Layout]) -> None:
    store, remote, layout = world
    store.fetch(KEY, remote.url)
    store.checkout(KEY, remote.first)
    damage(store, layout)
    store.remove(KEY)
    assert store.origin_url(KEY) is None and not layout.repository_dir(KEY).exists()
    assert [p.name for p in layout.repositories.glob("*~damaged")] == [f".{KEY}~damaged"]


# -- what resolving a desired state asks of the store (engine/observe/targets.py) -----------------


def test_what_a_remote_advertises_and_what_the_last_fetch_saw(
    world: tuple[Resolving, Remote, Layout],
) -> None:
    store, remote, _ = world
    refs = store.ls_remote(remote.url)
    assert refs.resolve(None) == refs.resolve(remote.branch) == remote.second
    assert refs.resolve("v1") == remote.first
    assert store.local_refs(KEY) is None
    store.fetch(KEY, remote.url)
    seen = store.local_refs(KEY)
    assert seen is not None and seen.url == remote.url
    assert seen.resolve(None) == remote.second and seen.resolve("v1") == remote.first
    with pytest.raises(GitError):
        store.ls_remote(remote.url.replace("apps.git", "missing.git"))


def test_an_abbreviated_hash_expands_to_a_fetched_commit(
    world: tuple[Resolving, Remote, Layout],
) -> None:
    store, remote, _ = world
    assert store.resolve_local(KEY, remote.first[:10]) is None  # nothing fetched yet
    store.fetch(KEY, remote.url)
    assert store.resolve_local(KEY, remote.first[:10]) == remote.first
    assert store.resolve_local(KEY, remote.second[:10].upper()) == remote.second
    assert store.resolve_local(KEY, "main") is None  # not a hash: resolving asks the refs
    assert store.resolve_local(KEY, "0" * 40) is None


def test_a_folders_tree_and_where_the_checkout_is(
    world: tuple[Resolving, Remote, Layout],
) -> None:
    store, remote, layout = world
    assert store.location(KEY) == layout.repository_dir(KEY)
    store.fetch(KEY, remote.url)
    assert store.folder_tree(KEY, remote.first, "alpha") == remote.trees[remote.first]
    assert store.folder_tree(KEY, remote.first, "nowhere") is None
    assert store.folder_files(KEY, remote.first, "alpha") == ["run.sh"]
    assert store.folder_files(KEY, remote.first, "nowhere") == []
    assert store.read_file(KEY, remote.first, "alpha/run.sh") == b"echo one\n"
    with pytest.raises(GitError):
        store.read_file(KEY, remote.first, "alpha/run.sh", limit=4)


def test_fetching_objects_moves_no_checkout(world: tuple[Resolving, Remote, Layout]) -> None:
    store, remote, _ = world
    store.fetch_objects(KEY, remote.url)  # a missing checkout is made, as by fetch
    assert store.origin_url(KEY) == remote.url and store.has_commit(KEY, remote.second)
    store.checkout(KEY, remote.first)
    store.fetch_objects(KEY, remote.url)
    assert store.head(KEY) == remote.first


@pytest.mark.parametrize(("ref", "which"), [(None, "second"), ("v1", "first"),
                                            ("main", "second"), ("short", "first")])
def test_resolving_a_desired_state_reads_the_same_from_either_store(
    world: tuple[Resolving, Remote, Layout], ref: str | None, which: str,
) -> None:
    """engine/observe/targets.py resolves against the port: the twin gives what the real store
    gives, online, and offline from what the last fetch saw."""
    from reconciler.engine.observe.targets import Fetch, resolve
    from schemas.desired import DesiredState

    store, remote, layout = world
    wanted = remote.first[:10] if ref == "short" else ref
    desired = DesiredState.model_validate(
        {"version": 2, "repositories": [{"url": remote.url, "ref": wanted}]})
    online = resolve(desired, base_dir=layout.root, store=store, fetch=Fetch.CHECKOUT)
    (target,) = online.repositories
    assert target.commit is not None and target.commit == getattr(remote, which)
    assert store.has_commit(target.key, target.commit)
    offline = resolve(desired, base_dir=layout.root, store=store, fetch=Fetch.OFFLINE)
    assert offline.repositories[0].commit == target.commit
