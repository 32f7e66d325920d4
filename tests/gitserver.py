"""Real git servers for integration tests: a `git daemon` on loopback and repos built with git.

The adapter under test must never shell out to git, but the tests may: building fixtures with
the real git CLI and serving them with the real `git daemon` checks lpam against the same
server behaviour it meets in the field (peeled tags, symref HEAD, "no such repository").
Everything binds to 127.0.0.1 and lives below the directories the caller passes in.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import TypeVar

FIXED_ENV = {
    "GIT_AUTHOR_NAME": "Test Author",
    "GIT_AUTHOR_EMAIL": "author@example.com",
    "GIT_AUTHOR_DATE": "2024-01-01T00:00:00+00:00",
    "GIT_COMMITTER_NAME": "Test Committer",
    "GIT_COMMITTER_EMAIL": "committer@example.com",
    "GIT_COMMITTER_DATE": "2024-01-01T00:00:00+00:00",
    "GIT_CONFIG_NOSYSTEM": "1",
}


def git_env(home: Path) -> dict[str, str]:
    """The environment for git subprocesses: no user config, fixed identities and dates."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_") and k != "HOME"}
    env.update(FIXED_ENV)
    env["HOME"] = str(home)
    return env


def run_git(*args: str, cwd: Path, env: dict[str, str]) -> str:
    """Run git with a fixed default branch, returning its stripped stdout."""
    done = subprocess.run(
        ["git", "-c", "init.defaultBranch=main", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    if done.returncode != 0:
        raise RuntimeError(f"git {' '.join(args)} failed: {done.stderr.strip()}")
    return done.stdout.strip()


def free_port() -> int:
    """A port that was free a moment ago (the daemon start is retried if it is taken since)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextlib.contextmanager
def closed_port() -> Iterator[int]:
    """A loopback port that refuses every connection for the block: bound and never
    listening, so no other server (another test's, beside this one) can take it meanwhile,
    as it could take a port that `free_port` found free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        yield int(sock.getsockname()[1])


def _accepts(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


_Daemon = TypeVar("_Daemon", bound="GitDaemon")


class GitDaemon:
    """`git daemon` serving every repository under `base` on a free loopback port."""

    def __init__(self, base: Path, *, home: Path, log: Path | None = None,
                 receive_pack: bool = False) -> None:
        self.receive_pack = receive_pack  # accept pushes (the fleet's status branches)
        self.base = base
        self.env = git_env(home)
        self.port = 0
        self.log = log  # with a log, the daemon runs --verbose and writes its stderr there
        self._proc: subprocess.Popen[bytes] | None = None

    def url(self, name: str) -> str:
        return f"git://127.0.0.1:{self.port}/{name}"

    def __enter__(self: _Daemon) -> _Daemon:
        self.base.mkdir(parents=True, exist_ok=True)
        for _attempt in range(5):
            self.port = free_port()
            verbose = ["--verbose"] if self.log is not None else []
            with contextlib.ExitStack() as stack:
                err = (stack.enter_context(self.log.open("ab")) if self.log is not None
                       else subprocess.DEVNULL)
                self._proc = subprocess.Popen(
                    [
                        "git", "daemon", "--reuseaddr", *verbose, f"--base-path={self.base}",
                        "--export-all", "--listen=127.0.0.1", f"--port={self.port}",
                        "--informative-errors", "--enable=upload-pack",
                        *(["--enable=receive-pack"] if self.receive_pack else []),
                        str(self.base),
                    ],
                    env=self.env, stdout=subprocess.DEVNULL, stderr=err,
                    start_new_session=True,  # `git daemon` runs git-daemon as a child: kill both
                )
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and self._proc.poll() is None:
                if _accepts(self.port):
                    return self
                time.sleep(0.05)
            self._stop()
        raise RuntimeError("git daemon did not start on 127.0.0.1 after 5 attempts")

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._stop()

    def stop(self) -> None:
        """Take the server away (no network from here on); idempotent."""
        self._stop()

    def _stop(self) -> None:
        if self._proc is not None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self._proc.pid, signal.SIGKILL)
            self._proc.wait(timeout=10)
            self._proc = None


class RepoBuilder:
    """A bare repository `base/NAME` plus a work clone that commits are made and pushed from."""

    def __init__(self, base: Path, name: str, *, work_root: Path, home: Path) -> None:
        self.bare = base / name
        self.work = work_root / name
        self.env = git_env(home)
        self.bare.parent.mkdir(parents=True, exist_ok=True)
        self.work.mkdir(parents=True)
        run_git("init", "--bare", "--quiet", str(self.bare), cwd=self.bare.parent, env=self.env)
        run_git("init", "--quiet", cwd=self.work, env=self.env)
        run_git("remote", "add", "origin", str(self.bare), cwd=self.work, env=self.env)

    def git(self, *args: str) -> str:
        return run_git(*args, cwd=self.work, env=self.env)

    def write(self, path: str, content: str, *, executable: bool = False) -> None:
        target = self.work / path
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(content)
        target.chmod(0o755 if executable else 0o644)

    def symlink(self, path: str, points_to: str) -> None:
        target = self.work / path
        target.parent.mkdir(parents=True, exist_ok=True)
        target.symlink_to(points_to)

    def commit(self, message: str, files: dict[str, str] | None = None) -> str:
        """Write `files`, commit everything and return the new commit's hash."""
        for path, content in (files or {}).items():
            self.write(path, content)
        self.git("add", "--all")
        self.git("commit", "--quiet", "--allow-empty", "-m", message)
        return self.git("rev-parse", "HEAD")

    def branch(self, name: str, start: str = "HEAD") -> None:
        self.git("branch", "--force", name, start)

    def switch(self, name: str) -> None:
        self.git("checkout", "--quiet", name)

    def tag(self, name: str, target: str = "HEAD", *, message: str | None = None) -> None:
        """A lightweight tag, or an annotated one when `message` is given."""
        if message is None:
            self.git("tag", name, target)
        else:
            self.git("tag", "-a", name, "-m", message, target)

    def push(self) -> None:
        """Publish every branch and tag, moved ones included."""
        self.git("push", "--quiet", "--force", "--all", "origin")
        self.git("push", "--quiet", "--force", "--tags", "origin")

    def rev(self, rev: str) -> str:
        return self.git("rev-parse", rev)
