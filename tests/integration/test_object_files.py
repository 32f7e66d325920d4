"""Status's reader of committed files (adapters/objectfiles.py) answers as GitStore does,
from git's own files: loose objects, packs whose deltas name their base by offset or by
name, links and submodules not followed, a file too large refused; what it cannot answer
for certain is GitStore's to answer."""

from __future__ import annotations

import stat
from collections.abc import Callable
from pathlib import Path

import pytest

from reconciler.adapters.git import GitStore
from reconciler.adapters.objectfiles import ObjectFiles
from reconciler.base.errors import GitError, StoreDamagedError
from reconciler.base.layout import Layout
from tests.gitserver import git_env, run_git

KEY = "apps"
TEXT = "".join(f"line {i}\n" for i in range(3000))  # large enough for git to store deltas


def fast_only(layout: Layout) -> ObjectFiles:
    """An ObjectFiles that fails the test where it would ask GitStore."""
    files = ObjectFiles(layout)

    def asked() -> GitStore:
        raise AssertionError("asked GitStore")

    files._git = asked  # type: ignore[method-assign]
    return files


def outcome(read: Callable[[], object]) -> object:
    """What a read returned, or the kind of error it raised."""
    try:
        return read()
    except Exception as exc:  # the error is the outcome compared
        return type(exc)


def history(layout: Layout, home: Path, *, repack: list[str]) -> list[str]:
    """A checkout of KEY with a file edited over several commits, a link, a submodule entry
    and a large file; packed by `git REPACK...`, then one more commit left loose."""
    work, env = layout.repository_dir(KEY), git_env(home)
    work.mkdir(parents=True)
    run_git("init", "--quiet", cwd=work, env=env)
    (work / "app").mkdir()
    (work / "app/service").symlink_to("/etc/passwd")
    (work / "big.bin").write_bytes(b"\0" * (5 * 1024 * 1024))
    commits = []
    for round_ in range(4):
        (work / "app/description.txt").write_text(TEXT.replace("line 7\n", f"line {round_}\n"))
        run_git("add", "--all", cwd=work, env=env)
        run_git("commit", "--quiet", "-m", f"round {round_}", cwd=work, env=env)
        commits.append(run_git("rev-parse", "HEAD", cwd=work, env=env))
    blob = run_git("rev-parse", "HEAD:app/description.txt", cwd=work, env=env)
    run_git("update-index", "--add", "--cacheinfo", f"160000,{blob},vendor", cwd=work, env=env)
    run_git("commit", "--quiet", "-m", "a submodule", cwd=work, env=env)
    run_git(*repack, cwd=work, env=env)
    (work / "app/description.txt").write_text("loose\n")
    run_git("commit", "--quiet", "-am", "loose", cwd=work, env=env)
    commits.append(run_git("rev-parse", "HEAD", cwd=work, env=env))
    return commits


@pytest.mark.parametrize("repack", [
    ["repack", "-q", "-a", "-d", "-f"],  # deltas name their base by offset (OFS_DELTA)
    ["-c", "repack.useDeltaBaseOffset=false", "repack", "-q", "-a", "-d", "-f"],  # REF_DELTA
], ids=["offset-deltas", "named-deltas"])
def test_reads_as_the_git_store_reads(tmp_path: Path, hermetic_env: Path,
                                      repack: list[str]) -> None:
    layout = Layout(tmp_path / "root")
    commits = history(layout, hermetic_env, repack=repack)
    files, store = fast_only(layout), GitStore(layout)
    paths = ["app/description.txt", "./app//description.txt", "app/service", "app", "",
             "vendor", "vendor/x", "app/description.txt/x", "missing"]
    for commit in commits:
        assert files.has_commit(KEY, commit)
        for path in paths:
            assert files.read_file(KEY, commit, path) == store.read_file(KEY, commit, path), \
                (commit, path)
    assert files.read_file(KEY, commits[0], "app/description.txt") == \
        TEXT.replace("line 7\n", "line 0\n").encode()
    assert files.read_file(KEY, commits[-1], "app/service") is None  # a link: not followed
    tree = run_git("rev-parse", f"{commits[0]}^{{tree}}", cwd=layout.repository_dir(KEY),
                   env=git_env(hermetic_env))
    assert not files.has_commit(KEY, tree)  # an object, but no commit
    with pytest.raises(GitError, match="5242880 bytes"):
        files.read_file(KEY, commits[0], "big.bin")
    assert files.read_file(KEY, commits[0], "big.bin", limit=6 * 1024 * 1024) == \
        b"\0" * (5 * 1024 * 1024)


def test_what_it_cannot_find_is_the_git_stores_to_answer(tmp_path: Path,
                                                         hermetic_env: Path) -> None:
    """A commit that is not there, or a pack it cannot read, is asked again of GitStore:
    the answers (and the damage checks behind them) stay GitStore's."""
    layout = Layout(tmp_path / "root")
    commits = history(layout, hermetic_env, repack=["gc", "--quiet"])
    files, asked = ObjectFiles(layout), []
    real = files._git

    def counted() -> GitStore:
        asked.append(True)
        return real()

    files._git = counted  # type: ignore[method-assign]
    assert not files.has_commit(KEY, "0" * 40)
    assert asked
    assert files.read_file("elsewhere", commits[0], "app/description.txt") is None
    (index,) = (layout.repository_dir(KEY) / ".git/objects/pack").glob("*.idx")
    index.chmod(stat.S_IRUSR | stat.S_IWUSR)
    index.write_bytes(b"\0" * 64)  # not an index of version 2: GitStore decides
    asked.clear()
    files = ObjectFiles(layout)  # a new command: the index read afresh
    files._git = counted  # type: ignore[method-assign]
    read = (KEY, commits[0], "app/description.txt")
    assert outcome(lambda: files.read_file(*read)) == StoreDamagedError
    assert outcome(lambda: GitStore(layout).read_file(*read)) == StoreDamagedError
    assert asked
