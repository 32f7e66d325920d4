"""The ROS catkin workspace (`ros: {workspace, user}`): one immutable build per set of
source commits.

Why a space per build: catkin_make bakes the absolute path of its source space into the
devel space (`devel/.catkin`, hence ROS_PACKAGE_PATH) and compiles against it. A build made
in `<workspace>/.lpam/builds/<key>` with its own `src/` refers to nothing but itself, so it
stays usable whatever later happens to `<workspace>/src`, and a rollback is only a matter of
sourcing the older build's `devel/setup.bash` again: no compiler on the way back.

The workspace's own `src/<repo>` are relative links to the current build's sources, since
the field's scripts look there (`~/catkin_ws/src/<repo>`). catkin and rospkg follow links
and skip hidden folders, so neither ever crawls `.lpam/`, and the temporary name a link is
made under (`src/.<repo>.lpam-new`) is hidden from them too. A real folder found where a
link goes (a clone the old tool or a person made) is moved to `.lpam/replaced/`, never
deleted.

Builds run as the ROS user (through `runuser` when lpam is root, since the field works in
that user's workspace and must be able to rebuild it), from an argument list, with a small
environment (PATH, LANG, the user's HOME and names), in their own process group that is
killed whole on timeout or Ctrl-C (adapters/command.py). A build is `built` only once its
marker is written, after the files it vouches for are on disk: a power cut during a build
leaves a space without marker, which the next `prepare` removes.
"""

from __future__ import annotations

import contextlib
import os
import pwd
import re
import shutil
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

from reconciler.adapters.command import run_streamed
from reconciler.base.atomic import fsync_dir, write_atomic
from reconciler.base.errors import DETAIL_LINES, DependencyError
from reconciler.engine.execution.ports import DEFAULT_PATH, SOURCE_THEN_EXEC, Log

MARKER = ".lpam-built"
_KEY = re.compile(r"[0-9a-f]{8,64}")
_USER = re.compile(r"[a-z_][a-z0-9_-]*\$?")
_CONTEXT = 2  # lines shown before the first error line: the compiler's "In function …"

# Where catkin_make's output says a package failed; each `path` leads to that package.
_CMAKE_ERROR = re.compile(r"^CMake Error at (?P<path>.+?):\d+")  # relative to src/
_CMAKE_STACK = re.compile(r"^\s+(?P<path>\S.*?):\d+ \(")  # a call stack entry under it
_MAKE = re.compile(r"^g?make(?:\[\d+\])?: \*\*\* \[(?P<path>[^\]:]+?)/CMakeFiles/")  # build/
_COMPILER = re.compile(r"^(?P<path>/[^:]+):\d+(?::\d+)?: (?:fatal )?error\b")
_MANIFEST = re.compile(r"Error\(s\) in package '(?P<path>[^']+)'")
_NAME = re.compile(r"<name>\s*([^<]+?)\s*</name>")


def find_underlay() -> Path | None:
    """The first ROS distribution's setup file under /opt/ros; None when there is none
    (Debian's own catkin needs none)."""
    return next((c for c in sorted(Path("/opt/ros").glob("*/setup.bash")) if c.is_file()),
                None)


def build_failed(package: str | None, details: list[str]) -> DependencyError:
    """The error of a failed build, naming the package when the output said which."""
    where = f"package {package}" if package else "the workspace"
    return DependencyError(
        f"ROS workspace build failed in {where}", details=details,
        hint="the whole output of catkin_make is in the apply log; fix the package and "
        "apply again. The running app is untouched: it still uses its own build",
    )


def current_user() -> str:
    """The name of the user lpam runs as (its uid when the system has no name for it)."""
    uid = os.geteuid()
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)


class CatkinWorkspace:
    """The `Workspace` port with catkin_make; see the module's docstring."""

    def __init__(
        self, root: Path, user: str, *, python: str = "/usr/bin/python3",
        underlay: Path | Literal["auto"] | None = "auto", timeout: float = 3600.0,
    ) -> None:
        if not _USER.fullmatch(user):
            raise ValueError(f"not a user name: {user!r}")
        self.root = Path(os.path.abspath(root))
        self.user = user
        self.python = python
        self.underlay = find_underlay() if underlay == "auto" else underlay
        self.timeout = timeout

    @property
    def builds(self) -> Path:
        return self.root / ".lpam" / "builds"

    @property
    def replaced(self) -> Path:
        """Real folders found where a link to a build's sources was to go."""
        return self.root / ".lpam" / "replaced"

    def space(self, key: str) -> Path:
        if not _KEY.fullmatch(key):
            raise ValueError(f"not a workspace build key: {key!r}")
        return self.builds / key

    def built(self, key: str) -> bool:
        return (self.space(key) / MARKER).is_file()

    def setup_script(self, key: str) -> Path:
        return self.space(key) / "devel" / "setup.bash"

    def prepare(self, key: str) -> Path:
        """An empty `src/` for the build `key`, what was left of an unfinished build of it
        removed first. A finished build is left as it is: builds are immutable."""
        space = self.space(key)
        src = space / "src"
        if self.built(key):
            return src
        if space.is_symlink() or space.exists():
            _remove_space(space)
        self._folder(src)  # catkin_make writes build/, devel/ and src/CMakeLists.txt
        fsync_dir(self.builds)
        return src

    def build(self, key: str, *, log: Log) -> None:
        """Build the prepared sources of `key` (a no-op once built); DependencyError naming
        the failing package, with no marker left, when catkin_make fails."""
        space = self.space(key)
        if self.built(key):
            log(f"ROS workspace build {key} is already built")
            return
        if not (space / "src").is_dir():
            raise ValueError(f"workspace build {key} was not prepared")
        self._compile(space, log)
        write_atomic(space / MARKER, f"{key}\n")

    def _compile(self, space: Path, log: Log) -> None:
        """Run catkin_make in `space` as the ROS user; DependencyError when it fails."""
        argv = [*self._as_user(), *self._command(space)]
        env = self._env()
        if self.underlay is None and shutil.which("catkin_make", path=env["PATH"]) is None:
            raise DependencyError(
                "catkin_make is not installed, so the ROS workspace cannot be built",
                hint="install ROS Noetic (or Debian's `catkin` package) on this machine")
        diagnosis = _Diagnosis(space / "src")

        def both(line: str) -> None:
            diagnosis.feed(line)
            log(line)

        outcome = run_streamed(argv, log=both, deadline=time.monotonic() + self.timeout,
                               env=env, cwd=space)
        if outcome.code is None:
            raise DependencyError(
                f"ROS workspace build did not finish within {self.timeout:g} s and was "
                "killed", details=diagnosis.details(),
                hint="see how far it got in the apply log; the running app is untouched")
        if outcome.code == 127 and diagnosis.package is None:  # runuser, bash or exec
            raise DependencyError(
                "catkin_make could not be started" + (
                    f" after sourcing {self.underlay}" if self.underlay else ""),
                details=outcome.tail, hint="install ROS's catkin on this machine (or "
                "Debian's `catkin` package); the running app is untouched")
        if outcome.code != 0:
            raise build_failed(diagnosis.package, diagnosis.details())
        os.sync()  # the marker must not reach the disk before the files it vouches for

    def _command(self, space: Path) -> list[str]:
        # A vehicle's build is for running: test targets (and their tools, roslint, rostest)
        # are not built — they cost a Pi minutes, and a package whose tests need a linter
        # the car lacks (the field's joy_to_veh) would not build at all.
        argv = ["catkin_make", "-C", str(space), f"-DPYTHON_EXECUTABLE={self.python}",
                "-DCATKIN_ENABLE_TESTING=OFF"]
        if self.underlay is None:
            return argv
        return ["bash", "-c", SOURCE_THEN_EXEC, "lpam-build", str(self.underlay), *argv]

    def _as_user(self) -> list[str]:
        """The prefix that runs a command as the ROS user; DependencyError when lpam can
        neither be that user nor become it."""
        if os.geteuid() == 0:
            if self.user == "root":
                return []
            self._account()
            # -m: keep the environment given (runuser would set HOME from passwd).
            return ["runuser", "-u", self.user, "-m", "--"]
        me = current_user()
        if me != self.user:
            raise DependencyError(
                f"the ROS workspace is built as {self.user}, but lpam runs as {me}",
                hint=f"run lpam as root (sudo) or as {self.user}")
        return []

    def _env(self) -> dict[str, str]:
        """Nothing of lpam's own environment but PATH and LANG: a build must not depend on
        who started lpam, nor write into their home."""
        return {
            "PATH": os.environ.get("PATH") or DEFAULT_PATH,
            "LANG": os.environ.get("LANG") or "C.UTF-8",
            "HOME": str(self.root.parent),
            "USER": self.user,
            "LOGNAME": self.user,
            "PYTHONUNBUFFERED": "1",  # catkin_make's own lines in order with make's
        }

    def _account(self) -> pwd.struct_passwd:
        try:
            return pwd.getpwnam(self.user)
        except KeyError:
            raise DependencyError(
                f"the ROS user {self.user} does not exist on this machine",
                hint="create the user, or fix `ros: user` in the desired state") from None

    def _folder(self, path: Path) -> None:
        """Make the folder `path` of the workspace, and those above it up to the workspace
        itself, each given to the ROS user."""
        if path.is_dir():
            return
        if path == self.root:
            path.parent.mkdir(parents=True, exist_ok=True)  # the user's home: not lpam's
        else:
            self._folder(path.parent)
        path.mkdir()
        self._own(path)

    def _own(self, path: Path) -> None:
        """Give what lpam made (as root) to the ROS user, who builds and works in it."""
        if os.geteuid() == 0 and self.user != "root":
            account = self._account()
            os.lchown(path, account.pw_uid, account.pw_gid)

    def link(self, key: str, repos: Sequence[str]) -> None:
        """Point `root/src/<repo>` at the sources of build `key`, each replaced atomically;
        a real folder there is moved to `.lpam/replaced/` first."""
        sources = self.space(key) / "src"
        for repo in repos:
            if not _is_repo_name(repo):
                raise ValueError(f"not a repository folder name: {repo!r}")
            if not (sources / repo).is_dir():
                raise ValueError(f"workspace build {key} has no sources of {repo}")
        src = self.root / "src"
        self._folder(src)
        for repo in repos:
            self._link_one(src / repo, os.path.join("..", ".lpam", "builds", key, "src", repo))
        fsync_dir(src)

    def _link_one(self, dest: Path, target: str) -> None:
        if os.path.lexists(dest) and not dest.is_symlink():
            self._move_aside(dest)
        new = dest.with_name(f".{dest.name}.lpam-new")
        with contextlib.suppress(FileNotFoundError):
            new.unlink()  # left by a power cut between symlink and replace
        os.symlink(target, new)
        self._own(new)
        os.replace(new, dest)

    def _move_aside(self, path: Path) -> None:
        self._folder(self.replaced)
        aside = self.replaced / path.name
        number = 0
        while os.path.lexists(aside):
            number += 1
            aside = self.replaced / f"{path.name}.{number}"
        os.rename(path, aside)
        fsync_dir(self.replaced)
        fsync_dir(path.parent)

    def collect(self, keep: set[str]) -> None:
        """Remove every build, finished or not, that is neither in `keep` nor linked from
        the workspace's `src/`."""
        if not self.builds.is_dir():
            return
        spare = keep | self._linked()
        for space in sorted(self.builds.iterdir()):
            if _KEY.fullmatch(space.name) and space.name not in spare:
                _remove_space(space)
        fsync_dir(self.builds)

    def _linked(self) -> set[str]:
        """The builds the links in `root/src` point into (any link, lpam's or not)."""
        src = self.root / "src"
        linked: set[str] = set()
        if not src.is_dir():
            return linked
        for entry in src.iterdir():
            if not entry.is_symlink():
                continue
            target = os.path.normpath(os.path.join(src, os.readlink(entry)))
            parts = Path(os.path.relpath(target, self.builds)).parts
            if parts and _KEY.fullmatch(parts[0]):
                linked.add(parts[0])
        return linked


def _is_repo_name(name: str) -> bool:
    """One visible folder name: catkin skips hidden folders, and `/` or `..` would leave
    `src/`."""
    return bool(name) and "/" not in name and "\0" not in name and not name.startswith(".")


def _remove_space(space: Path) -> None:
    """Marker first, so that a removal cut short leaves an unfinished build, never a
    finished one with files missing."""
    if space.is_symlink():
        space.unlink()
        return
    with contextlib.suppress(FileNotFoundError):
        (space / MARKER).unlink()
        fsync_dir(space)
    shutil.rmtree(space)


class _Diagnosis:
    """Reads catkin_make's output as it streams by: the package the first error is in, and
    the lines from that error on (in a parallel build the last lines are often another
    package's, so the tail alone can miss the error)."""

    def __init__(self, src: Path) -> None:
        self.src = src
        self.package: str | None = None
        self._before: deque[str] = deque(maxlen=_CONTEXT)
        self._error: list[str] | None = None
        self._tail: deque[str] = deque(maxlen=DETAIL_LINES)
        self._in_cmake_error = False

    def feed(self, line: str) -> None:
        self._tail.append(line)
        if self._error is None:
            if _is_error(line):
                self._error = [*self._before, line]
            else:
                self._before.append(line)
        elif len(self._error) < DETAIL_LINES:
            self._error.append(line)
        if self.package is None:
            self.package = self._blame(line)

    def details(self) -> list[str]:
        return list(self._tail) if self._error is None else self._error

    def _blame(self, line: str) -> str | None:
        if self._in_cmake_error:  # its message, then "Call Stack (…):" and the calls
            if not line.startswith(("-- ", "CMake ")):
                found = _CMAKE_STACK.match(line)
                return self._package_at(found["path"]) if found else None
            self._in_cmake_error = False
        found = _CMAKE_ERROR.match(line)
        if found:
            self._in_cmake_error = True  # not in src/: a call stack entry may be
            return self._package_at(found["path"])
        for pattern in (_MAKE, _COMPILER, _MANIFEST):
            found = pattern.search(line)
            if found:
                return self._package_at(found["path"])
        return None

    def _package_at(self, path: str) -> str | None:
        """The package whose folder (under src/) holds `path`: the nearest package.xml."""
        here = Path(os.path.normpath(os.path.join(self.src, path)))
        for base in {self.src, self.src.resolve()}:
            if not here.is_relative_to(base):
                continue
            for folder in [here, *here.parents]:
                if folder == base:
                    break
                manifest = folder / "package.xml"
                if manifest.is_file():
                    return _manifest_name(manifest) or folder.name
        return None


def _is_error(line: str) -> bool:
    return any(p.search(line) for p in (_CMAKE_ERROR, _MAKE, _COMPILER, _MANIFEST)) or \
        "error:" in line.lower() or line.startswith("Traceback")


def _manifest_name(manifest: Path) -> str | None:
    try:
        found = _NAME.search(manifest.read_text(errors="replace"))
    except OSError:
        return None
    return found[1] if found else None
