"""Who may change what lpam runs as root (issue 31 item 4): the real `lpam` CLI, a real git
daemon, real files under the test's root, and the current user in the part of root.

What a user checks: after a first apply — even one run with a umask that would let the
group and everyone write (`umask 000`) — nothing lpam made under the root can be written
by anyone but its owner; and when someone opens a hole (makes the desired state
world-writable, the state record's directory group-writable, a directory above lpam's
files writable, or gives the store to another user), `lpam status` names that path and the
command that closes it, in the table and in `--json`, and says nothing once it is closed.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import stat
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from reconciler.base.layout import Layout
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

NOBODY = 65534  # a user that is not the one lpam runs as


@pytest.fixture
def apps(make_repo: Callable[[str], RepoBuilder]) -> RepoBuilder:
    """apps.git: a supervised app (ticker) and an app of scripts (alpha)."""
    builder = make_repo("apps.git")
    builder.write("libpanda-apps.yaml", CATALOG)
    builder.write("ticker/ticker.py", TICKER)
    add_app(builder, "alpha")
    builder.commit("ticker and alpha")
    builder.push()
    return builder


@pytest.fixture
def applied(lpam: Lpam, apps: RepoBuilder, git_daemon: GitDaemon) -> Lpam:  # noqa: F811
    """A root after a first apply of apps.git's two apps, run by an lpam whose umask lets
    everyone write what it creates."""
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


def exposed(car: Lpam) -> tuple[str, list[dict[str, object]]]:
    """What `lpam status` says of files others may change: its table's lines, its JSON."""
    table = car("status")
    assert table.returncode == 0, table.stderr
    lines = "\n".join(line for line in table.stdout.splitlines() if "chmod" in line
                      or "chown" in line)
    shown: list[dict[str, object]] = car.status()["exposed"]
    return lines, shown


def test_a_first_apply_leaves_nothing_others_may_write(applied: Lpam) -> None:
    assert writable_by_others(applied.root) == []
    assert exposed(applied) == ("", [])  # and status has nothing to say of it


def test_libpanda_app_manager_leaves_nothing_others_may_write(
    applied: Lpam, apps: RepoBuilder
) -> None:
    """LPAM's command line is a face of its own: a new commit fetched and applied by `-p`
    (new objects in the store, a new generation of alpha) under the same umask."""
    apps.commit("alpha changes", {"alpha/notes.txt": "x\n"})
    apps.push()
    before = {a["name"]: a["generation"] for a in applied.status()["installed"]}
    with umask(0):
        done = subprocess.run([sys.executable, "-m", "reconciler.frontends.shim", "-p"],
                              capture_output=True, text=True, timeout=120,
                              env={**os.environ, "LPAM_ROOT": str(applied.root)})
    assert done.returncode == 0, done.stderr
    after = {a["name"]: a["generation"] for a in applied.status()["installed"]}
    assert after["alpha"] != before["alpha"] and after["ticker"] == before["ticker"]
    assert writable_by_others(applied.root) == []


def _world_writable_desired_state(layout: Layout) -> Path:
    layout.desired_state.chmod(0o666)
    return layout.desired_state


def _group_writable_record_directory(layout: Layout) -> Path:
    layout.state_record.parent.chmod(0o775)
    return layout.state_record.parent


def _group_writable_directory_above(layout: Layout) -> Path:
    above = layout.root / "var" / "log"  # lpam's logs are in it; lpam did not make it so
    above.chmod(0o777)
    return above


def _store_given_to_another_user(layout: Layout) -> Path:
    if os.geteuid() != 0:
        pytest.skip("only root can give a directory to another user (chown): run as root "
                    "to test the owner's check")
    os.chown(layout.repositories, NOBODY, -1)
    return layout.repositories


@pytest.mark.parametrize(("hole", "problem", "fix"), [
    (_world_writable_desired_state, "world-writable", "chmod go-w"),
    (_group_writable_record_directory, "writable by its group", "chmod go-w"),
    (_group_writable_directory_above, "world-writable", "chmod go-w"),
    (_store_given_to_another_user, f"(uid {NOBODY})", "chown root"),
], ids=["desired state", "record's directory", "directory above", "store's owner"])
def test_status_names_a_path_others_may_change_and_how_to_close_it(
    applied: Lpam, hole: Callable[[Layout], Path], problem: str, fix: str
) -> None:
    path = hole(Layout(applied.root))
    command = f"{fix} {shlex.quote(str(path))}"
    lines, shown = exposed(applied)
    [line] = lines.splitlines()
    assert str(path) in line and problem in line and f"`{command}`" in line
    assert "can change what lpam runs as root" in line
    [entry] = shown
    assert entry["path"] == str(path) and entry["fix"] == command
    subprocess.run(command, shell=True, check=True)  # the fix, as the operator types it
    assert exposed(applied) == ("", [])
