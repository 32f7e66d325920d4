"""The shim's offline resolution reads a checkout's config and refs from git's own files
(adapters/gitfiles.py, through adapters/objectfiles.py and adapters/integrity.py) and
answers as GitStore does, on real checkouts: lpam's own fetch, then its refs packed by git
(with the peeled commits of annotated tags), a ref moved loose over its packed one, a
symbolic ref; what those files cannot tell for certain is GitStore's, or dulwich's, to
answer, and damage is named alike either way."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from reconciler.adapters import gitfiles, integrity
from reconciler.adapters.git import GitStore
from reconciler.adapters.objectfiles import ObjectFiles
from reconciler.base.layout import Layout
from tests.gitserver import GitDaemon, RepoBuilder, git_env, run_git
from tests.integration.test_object_files import fast_only

KEY = "apps"


def same_answers(files: ObjectFiles, store: GitStore, commits: list[str]) -> None:
    """`files` made afresh for each state of the checkout (one command's reads: its packs
    are listed once)."""
    assert files.origin_url(KEY) == store.origin_url(KEY) is not None
    assert files.local_refs(KEY) == store.local_refs(KEY)
    for commit in commits:
        assert files.resolve_local(KEY, commit) == store.resolve_local(KEY, commit) == commit
        assert files.resolve_local(KEY, commit.upper()) == commit
    assert files.damage(KEY) == store.damage(KEY) is None
    assert files.origin_url("absent") is None and files.local_refs("absent") is None
    assert files.resolve_local("absent", commits[0]) is None
    assert files.resolve_local(KEY, "main") is None


def read_for_certain(git: Path) -> None:
    """integrity's config and refs checks answered from the files, without dulwich."""
    gitfiles.config(git)
    integrity._refs_read(git)


@pytest.fixture
def fetched(tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
            hermetic_env: Path) -> tuple[Layout, list[str]]:
    """A checkout lpam fetched: branches, a lightweight tag, an annotated tag and an
    annotated tag of that tag, HEAD detached at a commit as apply leaves it."""
    repo = make_repo("apps.git")
    first = repo.commit("first", {"libpanda-apps.yaml": "apps: []\n"})
    repo.git("branch", "-M", "main")
    repo.tag("v1", message="the first")
    repo.git("tag", "-a", "v1-again", "-m", "a tag of a tag", "v1")
    second = repo.commit("second", {"alpha/description.txt": "alpha\n"})
    repo.tag("light")
    repo.branch("feature", first)
    repo.push()
    layout = Layout(tmp_path / "root")
    store = GitStore(layout, timeout=10)
    store.fetch(KEY, git_daemon.url("apps.git"))
    store.checkout(KEY, second)
    return layout, [first, second]


def test_reads_as_the_git_store_reads(fetched: tuple[Layout, list[str]],
                                      hermetic_env: Path) -> None:
    layout, commits = fetched
    store = GitStore(layout)
    git = layout.repository_dir(KEY) / ".git"
    env = git_env(hermetic_env)
    refs = store.local_refs(KEY)
    assert refs is not None and refs.resolve("v1") == refs.resolve("v1-again") == commits[0]
    assert refs.resolve("main") == refs.resolve("light") == commits[1]
    same_answers(fast_only(layout), store, commits)  # loose refs; tags peeled by reading
    read_for_certain(git)
    run_git("pack-refs", "--all", cwd=git.parent, env=env)  # peeled in packed-refs
    assert not (git / "refs/tags/v1").exists() and "^" in (git / "packed-refs").read_text()
    same_answers(fast_only(layout), store, commits)
    read_for_certain(git)
    run_git("update-ref", "refs/remotes/origin/feature", commits[1], cwd=git.parent, env=env)
    run_git("symbolic-ref", "refs/remotes/origin/HEAD", "refs/remotes/origin/main",
            cwd=git.parent, env=env)  # loose over packed, and a symbolic ref
    run_git("gc", "--quiet", cwd=git.parent, env=env)
    run_git("update-ref", "refs/remotes/origin/main", commits[0], cwd=git.parent, env=env)
    files = fast_only(layout)
    same_answers(files, store, commits)
    read_for_certain(git)
    moved = files.local_refs(KEY)
    assert moved is not None and moved.refs["refs/heads/main"] == commits[0]
    assert moved.refs["refs/heads/HEAD"] == commits[0]  # as dulwich follows it
    tree = run_git("rev-parse", f"{commits[0]}^{{tree}}", cwd=git.parent, env=env)
    assert files.resolve_local(KEY, tree) is store.resolve_local(KEY, tree) is None


def test_a_checkout_git_made_reads_alike(tmp_path: Path, hermetic_env: Path) -> None:
    """A checkout made by git itself (git's config, HEAD naming a branch both loose and
    packed), as the shim's test of imports makes one."""
    layout = Layout(tmp_path / "root")
    work, env = layout.repository_dir(KEY), git_env(hermetic_env)
    work.mkdir(parents=True)
    run_git("init", "--quiet", cwd=work, env=env)
    run_git("remote", "add", "origin", "git://example.invalid/apps.git", cwd=work, env=env)
    run_git("commit", "--quiet", "--allow-empty", "-m", "one", cwd=work, env=env)
    first = run_git("rev-parse", "HEAD", cwd=work, env=env)
    run_git("update-ref", "refs/remotes/origin/master", first, cwd=work, env=env)
    run_git("gc", "--quiet", cwd=work, env=env)
    run_git("commit", "--quiet", "--allow-empty", "-m", "two", cwd=work, env=env)
    second = run_git("rev-parse", "HEAD", cwd=work, env=env)
    same_answers(fast_only(layout), GitStore(layout), [first, second])
    read_for_certain(work / ".git")


def test_what_the_files_cannot_tell_is_the_git_stores(
        fetched: tuple[Layout, list[str]], hermetic_env: Path) -> None:
    """A config or a ref out of the ordinary, a commit not found here: GitStore answers."""
    layout, commits = fetched
    git = layout.repository_dir(KEY) / ".git"
    env = git_env(hermetic_env)
    store, asked = GitStore(layout), []
    files = ObjectFiles(layout)
    real = files._git

    def counted() -> GitStore:
        asked.append(True)
        return real()

    files._git = counted  # type: ignore[method-assign]
    run_git("config", "user.name", "a person; with a comment", cwd=git.parent, env=env)
    with pytest.raises(gitfiles.Unsure):
        gitfiles.config(git)
    same_answers(files, store, commits)
    assert asked
    run_git("config", "--unset", "user.name", cwd=git.parent, env=env)
    gitfiles.config(git)
    asked.clear()
    run_git("symbolic-ref", "refs/remotes/origin/two", "refs/remotes/origin/HEAD",
            cwd=git.parent, env=env)
    run_git("symbolic-ref", "refs/remotes/origin/HEAD", "refs/remotes/origin/main",
            cwd=git.parent, env=env)  # a symbolic ref naming another
    assert files.local_refs(KEY) == store.local_refs(KEY)
    assert asked
    asked.clear()
    assert files.resolve_local(KEY, "0" * 40) is store.resolve_local(KEY, "0" * 40) is None
    assert files.resolve_local(KEY, commits[0][:7]) == commits[0]  # abbreviated
    assert len(asked) == 2


def _lose_packs(git: Path) -> None:
    for pack in (git / "objects/pack").glob("*.pack"):
        pack.unlink()


DAMAGES: dict[str, Callable[[Path], object]] = {
    "a ref naming a lost object": lambda git: (git / "refs/heads/lost").write_text(
        "0" * 40 + "\n"),
    "a pack deleted": _lose_packs,
    "config garbage": lambda git: (git / "config").write_bytes(b"[remote \"origin\n\x00"),
    "HEAD naming garbage": lambda git: (git / "HEAD").write_text("garbage\n"),
}


@pytest.mark.parametrize("name", list(DAMAGES))
def test_damage_is_named_alike_either_way(fetched: tuple[Layout, list[str]],
                                          monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    layout, _ = fetched
    checkout = layout.repository_dir(KEY)
    DAMAGES[name](checkout / ".git")
    found = integrity.damage(checkout)
    assert found is not None
    assert ObjectFiles(layout).damage(KEY) == found

    def unsure(*_: object) -> object:
        raise gitfiles.Unsure("forced")

    for reader in ("config", "plain", "refs"):
        monkeypatch.setattr(gitfiles, reader, unsure)
    assert integrity.damage(checkout) == found  # dulwich's checks alone
