"""Who may change what lpam runs as root (issue 31 item 4): the real `lpam` CLI, a real git
daemon, real files under the test's root, and the current user in the part of root.

What a user checks: after a first apply — even one run with a umask that would let the
group and everyone write (`umask 000`) — nothing lpam made under the root can be written
by anyone but its owner.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import TICKER, Lpam, add_app
from tests.integration.test_fault_truth import lpam  # noqa: F401 (stops its supervisord)

CATALOG = """\
apps:
  - name: ticker
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0.5}
  - name: alpha
    path: alpha/
"""


@pytest.fixture
def applied(lpam: Lpam, make_repo: Callable[[str], RepoBuilder],  # noqa: F811
            git_daemon: GitDaemon) -> Lpam:
    """A root after a first apply of a supervised app (ticker) and an app of scripts
    (alpha), run by an lpam whose umask lets everyone write what it creates."""
    builder = make_repo("apps.git")
    builder.write("libpanda-apps.yaml", CATALOG)
    builder.write("ticker/ticker.py", TICKER)
    add_app(builder, "alpha")
    builder.commit("ticker and alpha")
    builder.push()
    lpam.desired("version: 2\nrepositories:\n"
                 f"  - url: {git_daemon.url('apps.git')}\n"
                 "apps:\n  - name: ticker\n  - name: alpha\n")
    with umask(0):
        done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    return lpam


@contextlib.contextmanager
def umask(mask: int) -> Iterator[None]:
    """The umask the lpam this test starts inherits (a user's login may have 002)."""
    before = os.umask(mask)
    try:
        yield
    finally:
        os.umask(before)


def writable_by_others(root: Path) -> list[str]:
    """Every file and directory under `root` that its group or other users may write
    (symbolic links have no mode of their own: not counted)."""
    found = []
    for folder, dirs, files in os.walk(root):
        for name in [*dirs, *files]:
            path = Path(folder) / name
            info = path.lstat()
            if not stat.S_ISLNK(info.st_mode) and info.st_mode & 0o022:
                found.append(f"{path.relative_to(root)} {stat.filemode(info.st_mode)}")
    return sorted(found)


def test_a_first_apply_leaves_nothing_others_may_write(applied: Lpam) -> None:
    assert writable_by_others(applied.root) == []

