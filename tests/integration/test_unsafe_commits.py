"""A commit with a path git must never write is refused cleanly, and the store recovers.

git itself will not commit such trees, so they are made with dulwich's object classes
directly in the served bare repository, as a hostile or broken server would offer them.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest
from dulwich.objects import Blob, Commit, ObjectID, Tree
from dulwich.refs import Ref
from dulwich.repo import Repo

from reconciler.adapters.git import GitStore
from reconciler.base.errors import GitError
from reconciler.base.layout import Layout
from tests.gitserver import GitDaemon, RepoBuilder

KEY = "lab/apps"
MAIN = Ref(b"refs/heads/main")
UNSAFE = [
    b".git/config",
    b"A/.git/hooks/post-checkout",
    b"A/.GIT/config",
    b"git~1/config",
    b"GIT~1/config",
    b"../escape",
    b"A/../../escape",
    b"./dot",
    b".git./config",  # NTFS drops trailing dots
    b".git::$INDEX_ALLOCATION/config",  # NTFS alternate data stream
    b"git~1:stream/config",  # the short name, with a stream
    b".GiT . /config",  # NTFS drops trailing dots and spaces, whatever their order
    b"A\\.git/config",  # a backslash separates path parts on Windows
    ".g\u200cit/config".encode(),  # HFS+ ignores zero-width characters
]


def write_tree(repo: Repo, files: dict[bytes, bytes]) -> ObjectID:
    """A tree holding `files` (path -> content), path elements taken as they are."""
    tree = Tree()
    subtrees: dict[bytes, dict[bytes, bytes]] = {}
    for path, content in files.items():
        head, sep, rest = path.partition(b"/")
        if sep:
            subtrees.setdefault(head, {})[rest] = content
        else:
            blob = Blob.from_string(content)
            repo.object_store.add_object(blob)
            tree.add(head, 0o100644, blob.id)
    for name, below in subtrees.items():
        tree.add(name, 0o040000, write_tree(repo, below))
    repo.object_store.add_object(tree)
    return tree.id


def commit_on_main(bare: Path, files: dict[bytes, bytes], message: str) -> str:
    """Commit `files` as the whole tree on top of the served `main`."""
    with Repo(str(bare)) as repo:
        commit = Commit()
        commit.tree = write_tree(repo, files)
        commit.parents = [repo.refs[MAIN]]
        commit.author = commit.committer = b"Hostile <h@example.com>"
        commit.author_time = commit.commit_time = 1704067200
        commit.author_timezone = commit.commit_timezone = 0
        commit.message = message.encode() + b"\n"
        repo.object_store.add_object(commit)
        repo.refs[MAIN] = commit.id
        return commit.id.decode("ascii")


def git_status(checkout: Path) -> str:
    return subprocess.run(
        ["git", "status", "--porcelain"], cwd=checkout, capture_output=True, text=True,
        check=True,
    ).stdout


@pytest.fixture
def served(make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon) -> RepoBuilder:
    repo = make_repo("lab/apps.git")
    repo.commit("clean", {"README": "clean\n", "app/run.sh": "echo run\n"})
    repo.push()
    return repo


@pytest.fixture
def layout(tmp_path: Path) -> Layout:
    return Layout(root=tmp_path / "root")


@pytest.fixture
def store(layout: Layout) -> GitStore:
    return GitStore(layout, timeout=10.0)


@pytest.mark.parametrize("unsafe", UNSAFE, ids=lambda p: p.decode("utf-8", "replace"))
def test_an_unsafe_path_is_refused_before_anything_is_written(
    served: RepoBuilder, git_daemon: GitDaemon, store: GitStore, layout: Layout, unsafe: bytes
) -> None:
    url = git_daemon.url("lab/apps.git")
    store.fetch(KEY, url)
    clean = served.rev("main")
    store.checkout(KEY, clean)
    checkout = layout.repository_dir(KEY)
    before = sorted(p.relative_to(checkout) for p in checkout.rglob("*") if ".git" not in p.parts)

    bad = commit_on_main(served.bare, {b"README": b"bad\n", b"B/new": b"x\n", unsafe: b"x\n"},
                         "hostile")
    store.fetch(KEY, url)
    with pytest.raises(GitError) as caught:
        store.checkout(KEY, bad)

    message = caught.value.message
    assert message.startswith(f"{KEY}: commit {bad} has an unsafe path '")
    assert message.endswith("lpam will not check it out") and "\n" not in message
    assert caught.value.hint
    assert store.head(KEY) == clean
    after = sorted(p.relative_to(checkout) for p in checkout.rglob("*") if ".git" not in p.parts)
    assert after == before and (checkout / "README").read_text() == "clean\n"
    assert not (checkout / ".git" / "lpam-checkout").exists()
    assert git_status(checkout) == ""
    assert store.local_edits(KEY) == []

    fixed = commit_on_main(served.bare, {b"README": b"fixed\n"}, "fixed")
    store.fetch(KEY, url)
    store.checkout(KEY, fixed)  # the same branch converges once a clean commit arrives
    assert store.head(KEY) == fixed
    assert (checkout / "README").read_text() == "fixed\n"
    assert git_status(checkout) == ""


@pytest.mark.parametrize("pending", ["unsafe", "missing"])
def test_a_marker_that_cannot_be_replayed_is_dropped(
    served: RepoBuilder, git_daemon: GitDaemon, store: GitStore, layout: Layout, pending: str
) -> None:
    url = git_daemon.url("lab/apps.git")
    clean = served.rev("main")
    bad = commit_on_main(served.bare, {b"A/.git/config": b"x\n"}, "hostile")
    fixed = commit_on_main(served.bare, {b"README": b"fixed\n"}, "fixed")
    store.fetch(KEY, url)
    store.checkout(KEY, clean)
    checkout = layout.repository_dir(KEY)
    # what an older lpam left after failing half-way through the unsafe commit
    marker = checkout / ".git" / "lpam-checkout"
    marker.write_text((bad if pending == "unsafe" else "0123456789" * 4) + "\n")

    store.checkout(KEY, fixed)

    assert store.head(KEY) == fixed
    assert not marker.exists()
    assert not (checkout / "A").exists()
    assert git_status(checkout) == ""


@pytest.mark.parametrize("unsafe", [b"app/../escape", b"app/.git/config", b"app/../../escape"],
                         ids=lambda p: p.decode())
def test_exporting_an_app_folder_with_an_unsafe_path_writes_nothing_outside(
    served: RepoBuilder, git_daemon: GitDaemon, store: GitStore, tmp_path: Path, unsafe: bytes
) -> None:
    bad = commit_on_main(served.bare, {b"app/run.sh": b"echo\n", unsafe: b"x\n"}, "hostile")
    store.fetch(KEY, git_daemon.url("lab/apps.git"))
    dest = tmp_path / "gen" / "alpha" / "g1"
    with pytest.raises(GitError, match="unsafe path"):
        store.export_folder(KEY, bad, "app", dest)
    assert not dest.exists()
    assert not any(p.name == "escape" for p in tmp_path.rglob("*"))


def test_a_file_over_the_limit_is_neither_checked_out_nor_exported(
    served: RepoBuilder, git_daemon: GitDaemon, layout: Layout, tmp_path: Path
) -> None:
    store = GitStore(layout, timeout=10.0, file_limit=1024 * 1024)
    clean = served.rev("main")
    big = served.commit("a model", {"app/model.bin": "\0" * (3 * 1024 * 1024)})
    served.push()
    store.fetch(KEY, git_daemon.url("lab/apps.git"))
    store.checkout(KEY, clean)
    with pytest.raises(GitError, match=r"'app/model\.bin' of 3 MiB; lpam writes no file over 1"):
        store.checkout(KEY, big)
    assert store.head(KEY) == clean and store.local_edits(KEY) == []
    with pytest.raises(GitError, match=r"model\.bin"):
        store.export_folder(KEY, big, "app", tmp_path / "gen")
    assert not (tmp_path / "gen").exists()
