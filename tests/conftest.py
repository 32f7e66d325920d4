"""Shared fixtures: a hermetic environment, and real git repositories served over git://."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder


@pytest.hookimpl(tryfirst=True)  # before the tmp_path plugin reads --basetemp
def pytest_configure(config: pytest.Config) -> None:
    """Two things of the process that runs the tests, whether pytest runs them itself or a
    pytest-xdist worker does.

    SIGINT is Ctrl-C, even when the suite was started in the background (a script's
    `cmd &`, often with nohup), which ignores it: every lpam a test starts would inherit the
    ignored SIGINT, and the tests that press Ctrl-C on an apply would wait for it in vain.

    A worker keeps its temporary folders in `<basetemp>/gw0`, not in the
    `<basetemp>/popen-gw0` xdist names. A unix socket's path holds at most 107 bytes, and
    lpam refuses a root whose supervisord socket (`<root>/run/lpam/supervisor.sock`, and
    the `.<pid>` supervisord binds first) would not fit; a test's root is
    `/tmp/pytest-of-USER/pytest-N/<test name, up to 32 bytes>/root`. The six bytes saved
    keep every test's socket within the limit, with a few bytes to spare, as in a serial
    run."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    worker = getattr(config, "workerinput", None)
    given = config.option.basetemp
    if worker is not None and given:
        path = Path(given)
        if path.name.startswith("popen-"):
            config.option.basetemp = str(path.with_name(str(worker["workerid"])))


@pytest.fixture(autouse=True)
def hermetic_env(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> Iterator[Path]:
    """No test sees the developer's git config, identity or HOME (dulwich's TestCase does so),
    and no test asks this machine's own systemd about anything: the service manager is
    supervisord under each test's root unless a test puts a recording `systemctl` on PATH."""
    home = tmp_path_factory.mktemp("home")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("LPAM_SERVICES", "supervisor")
    monkeypatch.delenv("XDG_CONFIG_HOME", raising=False)
    for name in list(os.environ):
        if name.startswith("GIT_"):
            monkeypatch.delenv(name)
    yield home


@pytest.fixture
def git_daemon(tmp_path_factory: pytest.TempPathFactory, hermetic_env: Path) -> Iterator[GitDaemon]:
    """A real `git daemon` on 127.0.0.1 serving the repositories `make_repo` builds; it
    accepts pushes, as a fleet's repository does for the cars' status branches."""
    with GitDaemon(tmp_path_factory.mktemp("served"), home=hermetic_env,
                   receive_pack=True) as daemon:
        yield daemon


@pytest.fixture
def make_repo(
    git_daemon: GitDaemon, tmp_path_factory: pytest.TempPathFactory, hermetic_env: Path
) -> Callable[[str], RepoBuilder]:
    """Build a repository served as `git_daemon.url(name)` (and on disk as `.bare`)."""
    work_root = tmp_path_factory.mktemp("work")

    def make(name: str) -> RepoBuilder:
        return RepoBuilder(git_daemon.base, name, work_root=work_root, home=hermetic_env)

    return make
