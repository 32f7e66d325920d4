"""The real catkin workspace, as the field uses it: what only catkin_make and roslaunch show.

- a build's devel space finds its packages in the build's own sources, and roslaunch runs
  their nodes from there;
- that stays true after the workspace's `src/` link has moved on to another build: a
  rollback can go back to a build without rebuilding it;
- a failure names the package and shows the compiler's (or cmake's) error line;
- the build sees only its small environment, with HOME in the workspace user's home;
- a build over its time, or interrupted, is killed with everything it started;
- as root, the build runs through `runuser` as the ROS user, who owns the spaces.

The real builds (about two seconds each) are shared by a module's tests where they can be;
roslaunch starts its own ROS master on a free port of 127.0.0.1, and every process a test
starts is killed by process group at its end.
"""

from __future__ import annotations

import contextlib
import os
import pwd
import shlex
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from reconciler.adapters.catkin import CatkinWorkspace, current_user
from reconciler.base.errors import DependencyError
from tests.catkin import COMPILE_ERROR, MARK_VAR, write_package
from tests.contract.test_services import alive, wait_for

# The module fixture `built` makes two real catkin builds; under pytest-xdist the file's
# tests stay on one worker (--dist loadgroup), so they are built once, not once per worker.
pytestmark = pytest.mark.xdist_group("catkin")

FIRST = "a1" * 4
SECOND = "b2" * 4
BROKEN = "c3" * 4
ENV = "d4" * 4

needs_catkin = pytest.mark.skipif(
    shutil.which("catkin_make") is None,
    reason="catkin_make is not on PATH (apt-get install catkin): no real build possible")
needs_roslaunch = pytest.mark.skipif(
    shutil.which("roslaunch") is None,
    reason="roslaunch is not on PATH (apt-get install python3-roslaunch rosout)")


def sourced(setup: Path, command: str, home: Path) -> str:
    """The output of `command` in bash after `source setup`, as a field script runs it."""
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(home),
           "LANG": "C.UTF-8", "ROS_HOME": str(home / "ros")}
    result = subprocess.run(["bash", "-c", f'source "$1" && {command}', "field", str(setup)],
                            env=env, capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def launch(setup: Path, package: str, file: str, scratch: Path) -> str:
    """roslaunch `package file` after sourcing `setup`, its own ROS master on a free local
    port; the first line its node writes. Everything it started is killed afterwards."""
    scratch.mkdir()
    mark = scratch / "mark"
    port = free_port()
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(scratch),
           "LANG": "C.UTF-8", "ROS_HOME": str(scratch / "ros"), MARK_VAR: str(mark),
           "ROS_MASTER_URI": f"http://127.0.0.1:{port}", "ROS_IP": "127.0.0.1"}
    argv = ["bash", "-c", 'source "$1" && shift && exec roslaunch "$@"', "field", str(setup),
            "-p", str(port), package, file]
    with (scratch / "roslaunch.log").open("wb") as out:
        proc = subprocess.Popen(argv, env=env, stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        started = wait_for(lambda: mark.is_file() and mark.read_text().endswith("\n"), 30)
        assert started, (scratch / "roslaunch.log").read_text()
        return mark.read_text().splitlines()[0]
    finally:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, sig)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=10)


@dataclass
class Built:
    ws: CatkinWorkspace
    home: Path  # for the commands the tests run, never the build's


def _build(ws: CatkinWorkspace, key: str, fill: Callable[[Path], object]) -> list[str]:
    lines: list[str] = []
    fill(ws.prepare(key))
    ws.build(key, log=lines.append)
    return lines


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Built:
    """Two builds of the same package `alpha` (repository `robot`), the second from other
    sources, in one workspace."""
    if shutil.which("catkin_make") is None:
        pytest.skip("catkin_make is not on PATH (apt-get install catkin)")
    base = tmp_path_factory.mktemp("catkin")
    ws = CatkinWorkspace(base / "home" / "circles" / "catkin_ws", current_user())
    for key in (FIRST, SECOND):
        _build(ws, key, lambda src: write_package(src / "robot" / "alpha", "alpha",
                                                  launch="run.launch", node="talker.py"))
    return Built(ws, tmp_path_factory.mktemp("field-home"))


@needs_roslaunch
def test_a_build_finds_its_packages_in_its_own_sources(built: Built) -> None:
    ws = built.ws
    found = sourced(ws.setup_script(FIRST), "roslaunch --files alpha run.launch", built.home)
    assert found.strip() == str(ws.space(FIRST) / "src/robot/alpha/launch/run.launch")
    share = sourced(ws.setup_script(SECOND), "catkin_find --first-only alpha", built.home)
    assert share.strip() == str(ws.space(SECOND) / "devel/share/alpha")


@needs_roslaunch
def test_a_build_still_runs_after_the_workspace_moved_on_to_another(
    built: Built, tmp_path: Path,
) -> None:
    ws = built.ws
    ws.link(FIRST, ["robot"])
    ws.link(SECOND, ["robot"])
    assert (ws.root / "src/robot").resolve() == ws.space(SECOND) / "src/robot"
    node = ws.space(FIRST) / "src/robot/alpha/scripts/talker.py"
    assert launch(ws.setup_script(FIRST), "alpha", "run.launch", tmp_path / "first") == \
        f"alpha {node}", "the older build runs its own sources, not the linked ones"
    node = ws.space(SECOND) / "src/robot/alpha/scripts/talker.py"
    assert launch(ws.setup_script(SECOND), "alpha", "run.launch", tmp_path / "second") == \
        f"alpha {node}"


@needs_catkin
def test_a_compile_error_is_shown_with_the_package_it_is_in(built: Built) -> None:
    ws = built.ws
    lines: list[str] = []

    def fill(src: Path) -> None:
        write_package(src / "robot" / "alpha", "alpha")
        write_package(src / "tools" / "gamma", "gamma", broken=True)

    fill(ws.prepare(BROKEN))
    with pytest.raises(DependencyError) as caught:
        ws.build(BROKEN, log=lines.append)
    error = caught.value
    assert error.message == "ROS workspace build failed in package gamma"
    compiler = [line for line in error.details if COMPILE_ERROR in line and "error" in line]
    assert compiler and compiler[0].startswith(str(ws.space(BROKEN) / "src/tools/gamma/src"))
    assert compiler[0] in error.render() and compiler[0] in lines
    assert not ws.built(BROKEN) and not (ws.space(BROKEN) / ".lpam-built").exists()
    assert ws.built(FIRST) and ws.built(SECOND), "other builds are untouched"


@needs_catkin
@pytest.mark.parametrize("cmake", [
    "find_package(lpam_missing_dependency REQUIRED)\n",  # CMake Error at <pkg>/CMakeLists.txt
    "catkin_package(CATKIN_DEPENDS lpam_missing_dependency)\n",  # … in catkin's own cmake
], ids=["find_package", "catkin_package"])
def test_a_cmake_error_names_the_package_whose_cmakelists_caused_it(
    tmp_path: Path, cmake: str,
) -> None:
    ws = CatkinWorkspace(tmp_path / "catkin_ws", current_user())
    src = ws.prepare(BROKEN)
    write_package(src / "robot" / "alpha", "alpha")
    write_package(src / "robot" / "delta", "delta")
    with (src / "robot" / "delta" / "CMakeLists.txt").open("a") as cmakelists:
        cmakelists.write(cmake)
    with pytest.raises(DependencyError) as caught:
        ws.build(BROKEN, log=lambda _line: None)
    assert caught.value.message == "ROS workspace build failed in package delta"
    assert any("lpam_missing_dependency" in line for line in caught.value.details)
    assert not ws.built(BROKEN)


@needs_catkin
def test_the_build_sees_only_its_own_environment_with_home_in_the_users_home(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, hermetic_env: Path,
) -> None:
    """The underlay (a ROS distribution's setup.bash) is sourced first: this one records
    the environment the build runs in."""
    for name in ("LPAM_ROOT", "ROS_PACKAGE_PATH", "PYTHONPATH", "CMAKE_PREFIX_PATH"):
        monkeypatch.setenv(name, "/from/lpam")
    dump = tmp_path / "env.txt"
    underlay = tmp_path / "opt-ros" / "setup.bash"
    underlay.parent.mkdir()
    underlay.write_text(f"env > {shlex.quote(str(dump))}\n")
    ws = CatkinWorkspace(tmp_path / "home" / "circles" / "catkin_ws", current_user(),
                         underlay=underlay)
    lines = _build(ws, ENV, lambda src: write_package(src / "robot" / "alpha", "alpha"))
    assert ws.built(ENV)
    assert any("source" in line and str(underlay) in line for line in lines)
    env = dict(line.split("=", 1) for line in dump.read_text().splitlines() if "=" in line)
    assert env["HOME"] == str(tmp_path / "home" / "circles")
    assert env["USER"] == current_user()
    bash_own = {"PWD", "SHLVL", "_", "OLDPWD"}
    assert set(env) - bash_own == {"PATH", "LANG", "HOME", "USER", "LOGNAME",
                                   "PYTHONUNBUFFERED"}
    assert list(hermetic_env.iterdir()) == [], "nothing is written to lpam's own HOME"


def _fake(bin_dir: Path, name: str, body: str) -> None:
    bin_dir.mkdir(exist_ok=True)
    (bin_dir / name).write_text(f"#!/bin/sh\n{body}")
    os.chmod(bin_dir / name, 0o755)


@pytest.fixture
def hanging(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[CatkinWorkspace]:
    """A workspace whose catkin_make starts a compiler that never ends (its pid in
    `<home>/compiler.pid`), prints `started` and waits for it."""
    _fake(tmp_path / "bin", "catkin_make",
          'sleep 300 &\necho $! > "$HOME/compiler.pid"\necho started\nwait\n')
    monkeypatch.setenv("PATH", f"{tmp_path / 'bin'}:{os.environ['PATH']}")
    ws = CatkinWorkspace(tmp_path / "home" / "catkin_ws", current_user(), underlay=None,
                         timeout=1.0)
    ws.prepare(FIRST)
    yield ws
    pid_file = tmp_path / "home" / "compiler.pid"
    if pid_file.exists():
        with contextlib.suppress(ProcessLookupError):
            os.kill(int(pid_file.read_text()), signal.SIGKILL)


def _compiler(ws: CatkinWorkspace) -> int:
    return int((ws.root.parent / "compiler.pid").read_text())


def test_a_build_over_its_time_is_killed_with_everything_it_started(
    hanging: CatkinWorkspace,
) -> None:
    started = time.monotonic()
    with pytest.raises(DependencyError) as caught:
        hanging.build(FIRST, log=lambda _line: None)
    assert time.monotonic() - started < 8
    assert "did not finish within 1 s" in caught.value.message
    assert wait_for(lambda: not alive(_compiler(hanging)), 10), "the compiler outlived lpam"
    assert not hanging.built(FIRST)


def test_an_interrupted_build_is_killed_with_everything_it_started(
    hanging: CatkinWorkspace,
) -> None:
    hanging.timeout = 60

    def interrupt(line: str) -> None:
        if line == "started":
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        hanging.build(FIRST, log=interrupt)
    assert wait_for(lambda: not alive(_compiler(hanging)), 10), "the compiler outlived lpam"
    assert not hanging.built(FIRST)


@pytest.mark.parametrize("underlay", [False, True], ids=["alone", "after-underlay"])
def test_a_missing_catkin_make_is_a_dependency_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, underlay: bool,
) -> None:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    os.symlink(shutil.which("bash") or "/bin/bash", bin_dir / "bash")
    monkeypatch.setenv("PATH", str(bin_dir))
    setup = tmp_path / "setup.bash"
    setup.write_text("true\n")
    ws = CatkinWorkspace(tmp_path / "catkin_ws", current_user(),
                         underlay=setup if underlay else None)
    ws.prepare(FIRST)
    with pytest.raises(DependencyError) as caught:
        ws.build(FIRST, log=lambda _line: None)
    assert caught.value.message == (
        f"catkin_make could not be started after sourcing {setup}" if underlay
        else "catkin_make is not installed, so the ROS workspace cannot be built")
    assert not ws.built(FIRST)


@pytest.mark.skipif(os.geteuid() != 0, reason="only root can hand folders to another user")
def test_as_root_the_build_runs_through_runuser_as_the_ros_user(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A recording `runuser` stands in for the real one (the ROS user here, `nobody`, could
    not enter the test's private temporary folder)."""
    nobody = pwd.getpwnam("nobody")
    bin_dir = tmp_path / "bin"
    _fake(bin_dir, "runuser", 'printf "%s\\n" "$@" > "$HOME/runuser.argv"\n'
          'env > "$HOME/runuser.env"\n')
    _fake(bin_dir, "catkin_make", "exit 1\n")
    monkeypatch.setenv("PATH", f"{bin_dir}:{os.environ['PATH']}")
    home = tmp_path / "home" / "nobody"
    ws = CatkinWorkspace(home / "catkin_ws", "nobody", underlay=None)
    src = ws.prepare(FIRST)
    write_package(src / "robot" / "alpha", "alpha")
    owners = {p.stat().st_uid for p in (ws.root, ws.root / ".lpam", ws.space(FIRST), src)}
    assert owners == {nobody.pw_uid}, "the ROS user owns the workspace lpam made"
    assert home.stat().st_uid == 0, "the home is the system's to make, not lpam's"
    ws.build(FIRST, log=lambda _line: None)
    assert (home / "runuser.argv").read_text().splitlines() == [
        "-u", "nobody", "-m", "--", "catkin_make", "-C", str(ws.space(FIRST)),
        "-DPYTHON_EXECUTABLE=/usr/bin/python3", "-DCATKIN_ENABLE_TESTING=OFF"]
    env = dict(line.split("=", 1) for line in (home / "runuser.env").read_text().splitlines())
    assert (env["HOME"], env["USER"], env["LOGNAME"]) == (str(home), "nobody", "nobody")
    ws.link(FIRST, ["robot"])
    assert (ws.root / "src").stat().st_uid == nobody.pw_uid
    assert (ws.root / "src" / "robot").lstat().st_uid == nobody.pw_uid


@pytest.mark.skipif(os.geteuid() != 0, reason="only root can build as another user")
def test_a_ros_user_the_system_lacks_is_named(tmp_path: Path) -> None:
    ws = CatkinWorkspace(tmp_path / "catkin_ws", "lpam-no-such-user", underlay=None)
    with pytest.raises(DependencyError, match="ROS user lpam-no-such-user does not exist"):
        ws.prepare(FIRST)


def test_lpam_as_another_user_refuses_to_build(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    ws = CatkinWorkspace(tmp_path / "catkin_ws", "lpam-someone-else", underlay=None)
    monkeypatch.setattr(os, "geteuid", lambda: 54321)  # neither root nor that user
    ws.prepare(FIRST)
    with pytest.raises(DependencyError) as caught:
        ws.build(FIRST, log=lambda _line: None)
    assert caught.value.hint == "run lpam as root (sudo) or as lpam-someone-else"
    assert not ws.built(FIRST)
