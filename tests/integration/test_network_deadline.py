"""`--network-timeout` is a deadline on each network operation's total time, on every transport.

Servers that accept and never answer, servers that drip a byte every half second (no
per-read timeout ever trips), and an `ssh` that never connects must all end in a one-line
GitError soon after the deadline, with no child process left behind; Ctrl-C and a killed
lpam must not leave one either. Timing is asserted loosely (deadline + 20 s): the point is
"not forever", and the machine running the tests may be busy.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import pytest

from reconciler.adapters.git import GitStore
from reconciler.base.errors import GitError
from reconciler.base.layout import Layout
from tests.gitserver import RepoBuilder, closed_port, free_port
from tests.hostile_servers import GIT_DRIP, HTTP_DRIP, HostileServer

KEY = "lab/apps"
TIMEOUT = 1.5
SLACK = 20.0
NO_ANSWER = re.escape(f"no answer within {TIMEOUT:g} s")


@pytest.fixture
def layout(tmp_path: Path) -> Layout:
    return Layout(root=tmp_path / "root")


def _parents() -> dict[int, int]:
    """pid → parent pid of every live (not zombie) process."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            found[int(entry.name)] = int(fields[1])
    return found


def _forkserver(pid: int) -> bool:
    """Whether `pid` runs the forkserver's program: the long-lived forkserver (or its
    resource tracker), which lives as long as the process that started it, by design — or
    a network child it forked, which inherits its command line."""
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False
    return any(part in cmdline for part in (b"multiprocessing.forkserver",
                                            b"multiprocessing.resource_tracker"))


def children(pid: int | None = None) -> list[int]:
    """Live descendants of `pid` (this process by default), the forkserver itself excluded:
    the network children are its children."""
    parents = _parents()
    todo, found = [os.getpid() if pid is None else pid], []
    while todo:
        parent = todo.pop()
        for child, its_parent in parents.items():
            if its_parent == parent:
                todo.append(child)
                if not _forkserver(child) or _forkserver(parent):
                    found.append(child)
    return found


def end(pid: int) -> None:
    """Kill a process a failed test would otherwise leave running."""
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)


def gone(pid: int, within: float = 5.0) -> bool:
    """Whether process `pid` has ended (a zombie awaiting its reaper counts as ended)."""
    until = time.monotonic() + within
    while time.monotonic() < until:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return True
        if state == "Z":
            return True
        time.sleep(0.05)
    return False


def assert_fails_in_time(operation: Callable[[], object], match: str) -> GitError:
    """`operation` fails with a one-line GitError, not forever, and leaves no child."""
    before = set(children())  # a git daemon the test started
    started = time.monotonic()
    with pytest.raises(GitError, match=match) as caught:
        operation()
    assert time.monotonic() - started < TIMEOUT + SLACK
    assert "\n" not in caught.value.message and caught.value.hint
    assert set(children()) <= before, "the network child outlived the operation"
    return caught.value


def assert_store_untouched(layout: Layout) -> None:
    repos = layout.repositories
    assert not repos.exists() or list(repos.iterdir()) == []


# -- servers that never finish --------------------------------------------------------------


@pytest.mark.parametrize("scheme", ["git", "http"])
@pytest.mark.parametrize("kind", ["black hole", "drip"])
def test_a_server_that_never_finishes_hits_the_deadline(
    layout: Layout, scheme: str, kind: str
) -> None:
    drip = None if kind == "black hole" else {"git": GIT_DRIP, "http": HTTP_DRIP}[scheme]
    store = GitStore(layout, timeout=TIMEOUT)
    with HostileServer(drip=drip) as server:
        url = server.url(scheme)
        error = assert_fails_in_time(lambda: store.fetch(KEY, url), NO_ANSWER)
        assert url in error.message and error.message.startswith("cannot fetch")
        assert error.hint and "network" in error.hint
        assert_fails_in_time(lambda: store.ls_remote(url), NO_ANSWER)
        assert server.connections >= 2  # the deadline, not a refused connection, ended them
    assert_store_untouched(layout)


def test_a_refetch_that_hits_the_deadline_changes_nothing(
    layout: Layout, make_repo: Callable[[str], RepoBuilder]
) -> None:
    repo = make_repo("lab/apps.git")
    commit = repo.commit("first", {"README": "one\n"})
    repo.push()
    store = GitStore(layout, timeout=TIMEOUT)
    store.fetch(KEY, str(repo.bare))
    store.checkout(KEY, commit)
    with HostileServer(drip=GIT_DRIP) as server:
        # the same checkout, its origin now pointing at a server that drips
        checkout = layout.repository_dir(KEY)
        config = checkout / ".git" / "config"
        config.write_text(config.read_text().replace(str(repo.bare), server.url("git")))
        assert_fails_in_time(lambda: store.fetch(KEY, server.url("git")), NO_ANSWER)
    assert store.head(KEY) == commit
    assert store.local_refs(KEY) is not None
    assert [p.name for p in layout.repositories.iterdir()] == [checkout.name]


# -- ssh, through the ssh binary ------------------------------------------------------------


@pytest.fixture
def hanging_ssh(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An `ssh` first on PATH that records its pid and then waits (almost) forever."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    pid_file = tmp_path / "ssh.pid"
    ssh = bin_dir / "ssh"
    ssh.write_text(f"#!/bin/sh\necho $$ > {pid_file}\nexec sleep 600\n")
    ssh.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    return pid_file


def test_ssh_that_never_answers_hits_the_deadline(layout: Layout, hanging_ssh: Path) -> None:
    store = GitStore(layout, timeout=TIMEOUT)
    url = f"ssh://127.0.0.1:{free_port()}/lab/apps.git"

    assert_fails_in_time(lambda: store.fetch(KEY, url), NO_ANSWER)

    assert hanging_ssh.exists(), "the test's ssh was not the one dulwich ran"
    ssh = int(hanging_ssh.read_text())
    try:
        assert gone(ssh), "ssh outlived the deadline"
    finally:
        end(ssh)
    assert_store_untouched(layout)


def test_what_a_failed_ssh_leaves_running_is_ended(
    layout: Layout, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    pid_file = tmp_path / "stray.pid"
    ssh = bin_dir / "ssh"  # fails at once, leaving a process behind in its group
    ssh.write_text(f"#!/bin/sh\nsleep 600 </dev/null >/dev/null 2>&1 &\necho $! > {pid_file}\n"
                   "exit 255\n")
    ssh.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    store = GitStore(layout, timeout=30)

    error = assert_fails_in_time(
        partial(store.ls_remote, f"ssh://127.0.0.1:{free_port()}/lab/apps.git"), "cannot list"
    )

    assert "no answer" not in error.message  # the child finished; it was not cut off
    stray = int(pid_file.read_text())
    try:
        assert gone(stray), "a process ssh started outlived the operation"
    finally:
        end(stray)


# -- interrupted or killed lpam ---------------------------------------------------------------


def test_ctrl_c_ends_the_network_child(layout: Layout) -> None:
    store = GitStore(layout, timeout=60)
    with HostileServer() as server:
        timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT))
        timer.start()
        started = time.monotonic()
        try:
            with pytest.raises(KeyboardInterrupt):
                store.fetch(KEY, server.url("git"))
        finally:
            timer.cancel()
        assert time.monotonic() - started < SLACK
    assert children() == []
    assert_store_untouched(layout)


def test_a_killed_lpam_takes_its_ssh_along(
    layout: Layout, hanging_ssh: Path, tmp_path: Path
) -> None:
    script = textwrap.dedent(f"""
        from pathlib import Path
        from reconciler.adapters.git import GitStore
        from reconciler.base.layout import Layout
        GitStore(Layout(root=Path({str(layout.root)!r})), timeout=600).ls_remote(
            "ssh://127.0.0.1:{free_port()}/lab/apps.git")
    """)
    lpam = subprocess.Popen([sys.executable, "-c", script])
    try:
        until = time.monotonic() + 30
        while not hanging_ssh.exists() and time.monotonic() < until and lpam.poll() is None:
            time.sleep(0.05)
        assert hanging_ssh.exists(), "ssh never started"
        ssh = int(hanging_ssh.read_text())
        started = [p for p in children(lpam.pid) if p != ssh]
        assert started, "no network child"
        helpers = [p for p, parent in _parents().items() if parent == lpam.pid and _forkserver(p)]
    finally:
        lpam.kill()
        lpam.wait(timeout=10)
    try:
        for pid in started:
            assert gone(pid), "a network child outlived lpam"
        assert gone(ssh), "ssh outlived lpam"
        for pid in helpers:
            assert gone(pid), "the forkserver outlived lpam"
    finally:
        for pid in [*started, ssh, *helpers]:
            end(pid)


# -- credentials and local paths ------------------------------------------------------------


def test_credentials_never_appear_in_errors(layout: Layout) -> None:
    store = GitStore(layout, timeout=TIMEOUT)
    with HostileServer() as server:
        url = server.url("http", userinfo="robot:s3cret")
        error = assert_fails_in_time(lambda: store.ls_remote(url), NO_ANSWER)
        assert "robot:***@127.0.0.1" in error.message
    closed = f"https://ghp_t0ken@127.0.0.1:{free_port()}/lab/apps.git"  # connection refused
    refused = assert_fails_in_time(lambda: store.fetch(KEY, closed), "cannot fetch")
    unusable = assert_fails_in_time(lambda: store.ls_remote("ftp://u:s3cret@host/x"), "not a git")
    for error in (refused, unusable):
        assert "s3cret" not in error.message and "t0ken" not in error.message
    assert "***@127.0.0.1" in refused.message


@pytest.mark.parametrize("scheme", ["git", "http", "https"])
def test_a_refused_connection_is_said_in_words(layout: Layout, scheme: str) -> None:
    """The field trial read urllib3's `HTTPConnectionPool(...): Max retries exceeded ...
    [Errno 111] Connection refused` and a bare `[Errno 111]`: what failed (fetching the
    URL), where (the host and port) and what to try, in words, on one line."""
    store = GitStore(layout, timeout=10)
    with closed_port() as port:
        url = f"{scheme}://127.0.0.1:{port}/lab/apps.git"
        for operation, action in ((partial(store.fetch, KEY, url), "fetch"),
                                  (partial(store.ls_remote, url),
                                   "list the branches and tags of")):
            error = assert_fails_in_time(operation, "refused")
            assert error.message == (f"cannot {action} {url}: the server refused the "
                                     f"connection (nothing listens at 127.0.0.1:{port})")
            assert error.hint is not None and "`lpam plan --offline`" in error.hint
            assert "?" not in error.render()
    assert_store_untouched(layout)


def test_a_local_url_that_is_not_a_directory_is_refused(layout: Layout, tmp_path: Path) -> None:
    plain = tmp_path / "plain-file"
    plain.write_bytes(b"not a repository\n")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    store = GitStore(layout, timeout=TIMEOUT)
    for url in ("/dev/zero", str(plain), str(fifo), fifo.as_uri()):
        assert_fails_in_time(partial(store.fetch, KEY, url), "not a directory")
        assert_fails_in_time(partial(store.ls_remote, url), "not a directory")
    assert_store_untouched(layout)


CUT_HANDOVER = textwrap.dedent("""
    import os, time
    from multiprocessing import forkserver
    from reconciler.adapters import deadline

    deadline._forkserver()            # lpam's forkserver, with lpam's preloads
    status_r, data_w = forkserver._forkserver.connect_to_new_process([])
    pid = forkserver.read_signed(status_r)
    os.close(data_w)                  # lpam dies before it hands the request over
    forkserver.read_signed(status_r)  # the child's exit code: it has finished
""")


def test_a_hand_over_cut_by_ctrl_c_prints_no_traceback() -> None:
    """Ctrl-C or a kill while lpam hands a request to the forkserver left the forked child
    reading half a request; multiprocessing then printed an EOFError traceback under lpam's
    own "interrupted" line. The forkserver's children leave quietly."""
    done = subprocess.run([sys.executable, "-c", CUT_HANDOVER], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
