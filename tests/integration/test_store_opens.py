"""A no-op plan opens each repository of the store once (issue 32 item 4: about nine
before, each reading the git config again): HEAD and origin's URL are read from git's
files, the integrity check reads refs and config without dulwich. Counted, not timed."""

from __future__ import annotations

import collections
import contextlib
import io
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from dulwich import repo as dulwich_repo

from reconciler.frontends.cli import main
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam

REPOS = 3


@contextlib.contextmanager
def counted_opens() -> Iterator[collections.Counter[str]]:
    opened: collections.Counter[str] = collections.Counter()
    original = dulwich_repo.Repo.__init__

    def counting(self: Any, root: Any, *args: Any, **kwargs: Any) -> None:
        opened[Path(str(root)).name] += 1
        original(self, root, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(dulwich_repo.Repo, "__init__", counting)
        yield opened


def test_a_no_op_plan_opens_each_repository_once(
    make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    lines = ["version: 2", "repositories:"]
    for n in range(REPOS):
        repo = make_repo(f"r{n}.git")
        commit = repo.commit("one", {"README": f"repository {n}\n"})
        repo.push()
        lines += [f"  - url: {git_daemon.url(f'r{n}.git')}", f"    ref: {commit}"]
    lpam = Lpam(tmp_path / "car")
    desired = lpam.desired("\n".join([*lines, "apps: []"]) + "\n")
    applied = lpam("apply", "--yes")
    assert applied.returncode == 0, applied.stderr
    with counted_opens() as opened, contextlib.redirect_stdout(io.StringIO()) as out, \
            contextlib.redirect_stderr(io.StringIO()):
        code = main(["--root", str(lpam.root), "plan", "-f", str(desired),
                     "--detailed-exitcode"])
    assert code == 0, out.getvalue()  # no changes
    assert opened == {f"r{n}": 1 for n in range(REPOS)}, opened
