"""An app's dependencies, end to end: the real `lpam` CLI, a real git daemon serving both the
app repository and a ROS repository (reached through `mirrors:`, as a car reaches a
laptop's hotspot), real pip from a wheel folder with PIP_NO_INDEX, real catkin_make, a real
roslaunch under a real supervisord, and an `apt-get` on PATH that records its calls (the
suite never installs packages) beside the machine's real dpkg-query.

What a user checks: the launch app runs from its own build, inside its Python environment;
an apply that changes nothing, or only parameters, builds and installs nothing (even with
the wheel folder gone); a ROS commit that does not build, or an apt package that cannot be
found, fails before the cutover and leaves the running app alone.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from tests.catkin import MARK_VAR, write_package
from tests.contract.test_packages import ABSENT, recording_apt_get
from tests.gitserver import GitDaemon, RepoBuilder, free_port
from tests.integration.apps import Lpam
from tests.wheels import write_wheel

pytestmark = pytest.mark.skipif(
    shutil.which("catkin_make") is None or shutil.which("roslaunch") is None,
    reason="needs Debian's catkin and python3-roslaunch (the README's test command installs "
    "them when it runs as root)")

CATALOG = """\
apps:
  - name: vsl
    launch: lpam_demo_ros/talk.launch
    health: {{settle_seconds: 2}}
    dependencies: [{{apt: bash}}, {{pip3: "lpam-demo-speedo>=1.0"}}{extra}]
    ros_repositories:
      - {{owner: jmscslgroup, repo: can_to_ros, branch_or_hash: main}}
"""


@pytest.fixture
def lpam(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Lpam]:
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    write_wheel(wheels, "lpam-demo-speedo", "1.0", module="speedo", source="SPEED = 0\n")
    recording_apt_get(tmp_path / "bin", tmp_path / "apt-calls")
    monkeypatch.setenv("PATH", f"{tmp_path / 'bin'}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("PIP_NO_INDEX", "1")
    monkeypatch.setenv("PIP_FIND_LINKS", str(wheels))
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)
    runner = Lpam(tmp_path / "root")
    try:
        yield runner
    finally:
        shutdown(Layout(runner.root))  # the supervisord of this root, with roslaunch, by pid


@pytest.fixture
def ros_repo(make_repo: Callable[[str], RepoBuilder]) -> RepoBuilder:
    builder = make_repo("can_to_ros.git")
    write_package(builder.work / "lpam_demo_ros", "lpam_demo_ros", launch="talk.launch",
                  node="talker.py")
    builder.commit("a package with a launch file")
    builder.push()
    return builder


def apps_repo(make_repo: Callable[[str], RepoBuilder], extra: str = "") -> RepoBuilder:
    builder = make_repo("apps.git")
    builder.write("libpanda-apps.yaml", CATALOG.format(extra=extra))
    builder.write("vsl/description.txt", "velocity from the CAN bus\n")
    builder.commit("vsl")
    builder.push()
    return builder


def desired(lpam: Lpam, daemon: GitDaemon, **params: str) -> None:
    mark = lpam.root.parent / "talker.marks"
    lines = [
        "version: 1",
        f"repositories: [{{url: {daemon.url('apps.git')}}}]",
        f'mirrors: {{"https://github.com/jmscslgroup/": "{daemon.url("")}"}}',
        "app:",
        "  name: vsl",
        "  params:",
        f'    ROS_MASTER_URI: "http://127.0.0.1:{free_port()}"',
        '    ROS_IP: "127.0.0.1"',
        f'    {MARK_VAR}: "{mark}"',
    ]
    lines += [f'    {k}: "{v}"' for k, v in params.items()]
    lpam.desired("\n".join(lines) + "\n")


def marks(lpam: Lpam) -> list[str]:
    path = lpam.root.parent / "talker.marks"
    return path.read_text().splitlines() if path.exists() else []


def environ(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    return dict(item.decode().split("=", 1) for item in raw if b"=" in item)


def running_pid(lpam: Lpam) -> int:
    app = lpam.status()["app"]
    assert app is not None and app["unit"]["active"] == "active", app
    pid = app["unit"]["pid"]
    assert isinstance(pid, int)
    return pid


def test_a_launch_app_runs_from_its_own_build_inside_its_python_environment(
    lpam: Lpam, ros_repo: RepoBuilder, make_repo: Callable[[str], RepoBuilder],
    git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    apps_repo(make_repo)
    desired(lpam, git_daemon)
    plan = lpam("plan")
    assert plan.returncode == 0, plan.stderr
    assert "+ pip.lpam-demo-speedo>=1.0: not in the app's environment" in plan.stdout
    assert "+ ros.can_to_ros: at " in plan.stdout and "(build)" in plan.stdout
    assert "apt.bash" not in plan.stdout  # installed: nothing to say, nothing to run

    done = lpam("apply", "--yes", timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    pid = running_pid(lpam)
    # roslaunch ran the node from the build's own sources, in the ROS user's workspace
    [mark] = marks(lpam)
    package, path = mark.split(" ", 1)
    workspace = Path(lpam.root / "root/catkin_ws" if os.geteuid() == 0 else
                     lpam.root / "home" / os.environ.get("USER", "") / "catkin_ws")
    builds = workspace / ".lpam" / "builds"
    assert package == "lpam_demo_ros" and path.startswith(str(builds.resolve()))
    # where the field's scripts look: ~/catkin_ws/src/<repo>, the build's sources
    link = workspace / "src" / "can_to_ros"
    assert link.is_symlink() and (link / "lpam_demo_ros" / "package.xml").is_file()
    env = environ(pid)
    venv = env["VIRTUAL_ENV"]
    assert env["PATH"].startswith(f"{venv}/bin:")
    assert (Path(venv) / "bin" / "python").exists()
    probe = subprocess.run([f"{venv}/bin/python", "-c", "import speedo"], check=False)
    assert probe.returncode == 0  # the pip dependency, importable by the app's Python
    assert not (tmp_path / "apt-calls").exists()  # bash is installed: apt-get never ran

    # nothing changed, and the wheel folder is gone: nothing is built or installed
    shutil.rmtree(Path(os.environ["PIP_FIND_LINKS"]))
    again = lpam("plan", "--detailed-exitcode")
    assert again.returncode == 0, again.stdout + again.stderr
    assert "No changes" in again.stdout
    assert lpam("apply", "--yes").returncode == 0
    assert running_pid(lpam) == pid

    # only parameters change: restarted with them, no pip, no build
    desired(lpam, git_daemon, MODE="fast")
    changed = lpam("apply", "--yes", timeout=300)
    assert changed.returncode == 0, changed.stdout + changed.stderr
    assert "build:" not in changed.stdout and "pip:" not in changed.stdout
    assert "configure:" in changed.stdout
    assert environ(running_pid(lpam))["MODE"] == "fast"
    assert len(os.listdir(builds)) == 1


def test_a_ros_commit_that_does_not_build_leaves_the_running_app_alone(
    lpam: Lpam, ros_repo: RepoBuilder, make_repo: Callable[[str], RepoBuilder],
    git_daemon: GitDaemon,
) -> None:
    apps_repo(make_repo)
    desired(lpam, git_daemon)
    assert lpam("apply", "--yes", timeout=300).returncode == 0
    pid = running_pid(lpam)
    shutil.rmtree(ros_repo.work / "lpam_demo_ros")
    write_package(ros_repo.work / "lpam_demo_ros", "lpam_demo_ros", broken=True,
                  launch="talk.launch", node="talker.py")
    ros_repo.commit("does not compile")
    ros_repo.push()

    plan = lpam("plan")
    assert "~ ros.can_to_ros: " in plan.stdout and "(rebuild)" in plan.stdout
    failed = lpam("apply", "--yes", timeout=300)
    assert failed.returncode == 1
    assert "vsl: ROS workspace build failed in package lpam_demo_ros" in failed.stderr
    assert "lpam_undeclared_symbol" in failed.stderr  # the compiler's own words
    assert "Nothing was changed on the running app" in failed.stderr
    assert running_pid(lpam) == pid
    link = next(lpam.root.rglob("catkin_ws/src/can_to_ros"))
    space = link.resolve().parent.parent
    assert (space / ".lpam-built").exists()  # still the build that works


def test_an_apt_package_that_cannot_be_found_fails_before_the_cutover(
    lpam: Lpam, ros_repo: RepoBuilder, make_repo: Callable[[str], RepoBuilder],
    git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    apps_repo(make_repo, extra=f", {{apt: {ABSENT}}}")
    desired(lpam, git_daemon)
    plan = lpam("plan")
    assert f"+ apt.{ABSENT}: missing" in plan.stdout
    failed = lpam("apply", "--yes", timeout=300)
    assert failed.returncode == 1
    assert f"vsl: apt-get could not install {ABSENT}" in failed.stderr
    assert "Nothing was changed on the running app" in failed.stderr
    calls = (tmp_path / "apt-calls").read_text().splitlines()
    assert [c.split()[1] for c in calls] == ["install", "update", "install"]
    assert lpam.status()["app"] is None
