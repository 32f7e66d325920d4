"""Apps as supervised services, end to end: the real `lpam` CLI, a real git daemon, and a
real supervisord under each test's root running real processes.

What a user checks: the app's process runs (its pid is alive) and `lpam status` says so
from the service manager; a release that crashes is rolled back with the previous version
running again; a change of parameters alone restarts the app without its scripts or a
fetch; an operator's stop holds; a rollback returns offline and holds; an app LPAM
installed is taken over without two apps ever running; a kill mid-rollback converges.
Every test stops its supervisord by pid at the end.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from reconciler.adapters.services.supervisor import SupervisorServices, shutdown
from reconciler.base.layout import Layout
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, add_app, desired

TICKER = """\
import os, sys, time
root = os.environ["LPAM_ROOT"]
with open(os.path.join(root, "ticker.starts"), "a") as f:
    f.write(f"{os.getpid()} {os.environ.get('MODE', '-')} {os.getcwd()} "
            f"{os.environ['LPAM_APP_DIR']}\\n")
print("ticker up, mode", os.environ.get("MODE", "-"), flush=True)
while True:
    if os.environ.get("MODE") == "crash":
        time.sleep(0.3)
        print("ticker: lost the bus", flush=True)
        sys.exit(1)
    print("tick", flush=True)
    time.sleep(0.2)
"""

CATALOG = """\
apps:
  - name: ticker
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 1.5}
  - name: alpha
    path: alpha/
"""


@pytest.fixture
def lpam(tmp_path: Path) -> Iterator[Lpam]:
    runner = Lpam(tmp_path / "root")
    try:
        yield runner
    finally:
        shutdown(Layout(runner.root))  # the supervisord of this root, by its pid


@pytest.fixture
def repo(make_repo: Callable[[str], RepoBuilder]) -> RepoBuilder:
    builder = make_repo("apps.git")
    builder.write("libpanda-apps.yaml", CATALOG)
    builder.write("ticker/ticker.py", TICKER)
    builder.write("ticker/description.txt", "ticks\n")
    add_app(builder, "alpha")
    builder.commit("ticker and alpha")
    builder.push()
    return builder


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def unit(lpam: Lpam) -> dict[str, object]:
    app = lpam.status()["app"]
    assert app is not None
    found: dict[str, object] = app["unit"]
    return found


def starts(lpam: Lpam) -> list[list[str]]:
    log = lpam.root / "ticker.starts"
    return [line.split() for line in log.read_text().splitlines()] if log.exists() else []


def held_install(marker: str) -> str:
    """An install.sh that touches `$LPAM_ROOT/<marker>` and then, while `$LPAM_ROOT/hold`
    exists, runs on until the test creates `$LPAM_ROOT/release` (30 s at most): the test
    acts while the script runs, however long a busy machine takes to get there."""
    return (f'touch "$LPAM_ROOT/{marker}"\n'
            'if [ -e "$LPAM_ROOT/hold" ]; then\n'
            '  for _ in $(seq 600); do [ -e "$LPAM_ROOT/release" ] && break; sleep 0.05; done\n'
            'fi')


def test_a_scriptless_app_runs_under_supervisord_and_status_asks_it(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    lpam.desired(desired(git_daemon.url("apps.git"), "ticker", MODE="calm"))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    state = unit(lpam)
    assert state["active"] == "active" and isinstance(state["pid"], int)
    assert alive(state["pid"])
    assert lpam.status()["app"]["verified"] is True
    # it runs where LPAM's scripts would look for it, with its parameters
    [(pid, mode, cwd, app_dir)] = starts(lpam)
    assert (int(pid), mode) == (state["pid"], "calm")
    place = lpam.root / "etc/libpanda.d/apps/ticker"
    assert app_dir == str(place) and cwd == str(place.resolve())
    logs = lpam("logs", "-n", "2")
    assert logs.returncode == 0 and "tick" in logs.stdout
    assert lpam("plan", "--detailed-exitcode").returncode == 0
    # `lpam services shutdown` stops supervisord and the app with it
    down = lpam("services", "shutdown")
    assert down.returncode == 0 and "Stopped" in down.stdout
    deadline = time.monotonic() + 10
    while alive(int(pid)) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive(int(pid))


def test_an_app_stopped_behind_lpams_back_is_drift_and_apply_starts_it(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    lpam.desired(desired(git_daemon.url("apps.git"), "ticker"))
    assert lpam("apply", "--yes").returncode == 0
    SupervisorServices(Layout(lpam.root)).stop("lpam-app-ticker")  # someone else's stop
    assert lpam.status()["app"]["running"] is False
    plan = lpam("plan", "--detailed-exitcode")
    assert plan.returncode == 2
    assert "ticker is not running (unit lpam-app-ticker inactive" in plan.stdout
    assert lpam("apply", "--yes").returncode == 0
    assert unit(lpam)["active"] == "active"
    assert len(starts(lpam)) == 2


def test_a_release_that_crashes_is_rolled_back_and_the_previous_one_runs(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "ticker", MODE="calm"))
    assert lpam("apply", "--yes").returncode == 0
    repo.write("ticker/ticker.py", TICKER.replace('"crash"', '"calm"'))  # v2 crashes
    repo.commit("ticker v2")
    repo.push()
    done = lpam("apply", "--yes")
    assert done.returncode == 3, done.stderr
    # it dies before supervisord counts it as started, or while it settles: either way the
    # health check fails it
    assert "not active" in done.stderr or "did not stay up for 1.5 s" in done.stderr
    assert "ticker: lost the bus" in done.stderr  # the failed app's last output
    assert "Rolled back to ticker" in done.stderr
    status = lpam.status()
    assert status["last_apply"]["result"] == "rolled back"
    state = unit(lpam)
    assert state["active"] == "active" and alive(int(str(state["pid"])))
    # the one running is v1 (which never crashes), started again after v2
    pid = int(str(state["pid"]))
    assert starts(lpam)[-1][0] == str(pid)
    history = lpam("history", "--json")
    assert [h["result"] for h in json.loads(history.stdout)] == ["applied", "rolled back"]


def test_a_change_of_params_alone_restarts_without_scripts_fetch_or_generation(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    url = git_daemon.url("apps.git")
    commit = repo.git("rev-parse", "HEAD").strip()
    lpam.desired(desired(url, "ticker", ref=commit, MODE="calm"))
    assert lpam("apply", "--yes").returncode == 0
    generation = lpam.status()["app"]["generation"]
    lpam.desired(desired(url, "ticker", ref=commit, MODE="busy"))
    plan = lpam("plan")
    assert "parameters changed (MODE): restarted with the new values" in plan.stdout
    assert "stage:" not in plan.stdout and "install:" not in plan.stdout
    git_daemon.stop()  # pinned and already fetched: the change needs no network at all
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    app = lpam.status()["app"]
    assert app["generation"] == generation and app["params"] == {"MODE": "busy"}
    assert [s[1] for s in starts(lpam)] == ["calm", "busy"]
    assert alive(int(str(unit(lpam)["pid"])))


def test_an_operator_stop_holds_until_start(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    lpam.desired(desired(git_daemon.url("apps.git"), "ticker"))
    assert lpam("apply", "--yes").returncode == 0
    pid = int(str(unit(lpam)["pid"]))
    stopped = lpam("stop")
    assert stopped.returncode == 0, stopped.stderr
    assert "stays stopped" in stopped.stdout
    assert unit(lpam)["active"] == "inactive" and not alive(pid)
    plan = lpam("plan", "--detailed-exitcode")
    assert plan.returncode == 0 and "stopped by an operator" in plan.stdout
    assert lpam("apply", "--yes").returncode == 0
    assert unit(lpam)["active"] == "inactive"
    assert "stopped by operator" in lpam("status").stdout
    started = lpam("start")
    assert started.returncode == 0, started.stderr
    assert unit(lpam)["active"] == "active"
    assert lpam("plan", "--detailed-exitcode").returncode == 0


def test_rollback_returns_to_the_previous_generation_offline_and_holds(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "ticker", MODE="one"))
    assert lpam("apply", "--yes").returncode == 0
    first = lpam.status()["app"]["generation"]
    repo.write("ticker/VERSION", "2\n")
    repo.commit("ticker 2")
    repo.push()
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.status()["app"]["generation"] != first
    git_daemon.stop()  # no network from here on
    back = lpam("rollback", "--yes")
    assert back.returncode == 0, back.stderr
    assert lpam.status()["app"]["generation"] == first
    assert unit(lpam)["active"] == "active"
    plan = lpam("plan", "--offline", "--detailed-exitcode")
    assert plan.returncode == 0 and "held by `lpam rollback`" in plan.stdout
    applied = lpam("apply", "--yes", "--network-timeout", "5")
    assert "held by `lpam rollback`" in applied.stdout, applied.stderr
    assert lpam.status()["app"]["generation"] == first
    # a change of the desired state ends the hold
    lpam.desired(desired(url, "ticker", MODE="two"))
    changed = lpam("plan", "--offline", "--detailed-exitcode")
    assert changed.returncode == 2 and "held" not in changed.stdout


def test_an_app_lpam_installed_is_taken_over_before_another_is_installed(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    etc = lpam.root / "etc/libpanda.d"
    old = etc / "apps" / "pandarecord"
    old.mkdir(parents=True)
    for script in ("start", "stop", "install", "uninstall"):
        (old / f"{script}.sh").write_text(
            f'echo "pandarecord:{script}" >> "$LPAM_ROOT/events.log"\n')
    (etc / "app-manifest.yaml").write_text(
        "version: 0.0\nrepositories:\n  jmscslgroup/libpanda-default-apps: {branch: main}\n"
        "current: pandarecord  # LPAM's\n")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    plan = lpam("plan")
    assert "pandarecord was installed by LPAM" in plan.stdout and "taken over" in plan.stdout
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert lpam.events() == ["pandarecord:stop", "pandarecord:uninstall",
                             "alpha:install:", "alpha:start:"]
    manifest = (etc / "app-manifest.yaml").read_text()
    assert "current: alpha" in manifest and "jmscslgroup/libpanda-default-apps" in manifest
    assert (etc / "apps" / "alpha").is_symlink()
    assert old.is_dir()  # LPAM's own folder of another app is left where it was
    assert lpam("plan", "--detailed-exitcode").returncode == 0


def test_a_kill_during_a_rollback_converges_to_one_app(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    builder = make_repo("slow.git")
    builder.write("libpanda-apps.yaml", "apps:\n  - name: alpha\n  - name: beta\n")
    add_app(builder, "alpha", extra={"install": held_install("alpha-installing")})
    add_app(builder, "beta", extra={"start": "exit 1"})
    builder.commit("alpha installs slowly, beta never starts")
    builder.push()
    url = git_daemon.url("slow.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    (lpam.root / "alpha-installing").unlink()
    lpam.desired(desired(url, "beta"))
    (lpam.root / "hold").touch()
    proc = lpam.spawn("apply", "--yes")
    marker = lpam.root / "alpha-installing"
    try:
        deadline = time.monotonic() + 60
        while not marker.exists() and time.monotonic() < deadline:  # the rollback reinstalls
            time.sleep(0.05)
        assert marker.exists()
        os.killpg(proc.pid, signal.SIGKILL)  # lpam and the script: a power cut, as far as we care
        proc.wait(timeout=10)
    finally:
        (lpam.root / "release").touch()  # the orphaned install.sh ends
    again = lpam("apply", "--yes")  # beta fails again and is rolled back again
    assert again.returncode == 1
    final = lpam.status()["app"]
    assert final["name"] == "alpha" and final["status"] == "running"
    events = lpam.events()
    active: set[str] = set()
    for event in events:  # never two apps on the bus
        app, script = event.split(":")[:2]
        if script == "start":
            assert not active - {app}, events
            active.add(app)
        elif script == "stop":
            active.discard(app)
    assert events[-2:] == ["alpha:install:", "alpha:start:"]


def test_a_rollback_interrupted_by_ctrl_c_names_the_command_that_finishes_it(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    """Ctrl-C in a rollback's cutover: lpam says which command resumes it, and that command
    brings back the generation the rollback was returning to. (Another `lpam rollback`
    would go one generation further back: the field trial of issue 20 found lpam naming it.)"""
    first, proc = _rollback_reinstalling_v1(lpam, make_repo("resume.git"), git_daemon)
    try:
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in the terminal
        _, err = proc.communicate(timeout=30)
    finally:
        (lpam.root / "release").touch()
    assert proc.returncode == 130, err
    hint = err.split("run `", 1)[1].split("`", 1)[0]
    assert hint.split()[:3] == ["lpam", "--root", str(lpam.root)]
    done = lpam(*hint.split()[3:], "--yes")
    assert done.returncode == 0, done.stderr
    app = lpam.status()["app"]
    assert (app["generation"], app["status"]) == (first, "running")


def test_services_shutdown_without_supervisord_says_so(lpam: Lpam) -> None:
    done = lpam("services", "shutdown")
    assert done.returncode == 0 and "No supervisord was running" in done.stdout


def test_a_rollback_cut_off_by_a_kill_is_finished_by_the_next_apply(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    first, proc = _rollback_reinstalling_v1(lpam, make_repo("versions.git"), git_daemon)
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # lpam: its install.sh runs on, held
        proc.wait(timeout=10)
        git_daemon.stop()  # finishing a rollback needs no network
        plan = lpam("plan", "--offline")  # while the cut-off install.sh still runs
        assert "the rollback to alpha" in plan.stderr and "install:alpha@" in plan.stdout
    finally:
        (lpam.root / "release").touch()  # the orphaned install.sh ends; apply waits for it
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    app = lpam.status()["app"]
    assert (app["generation"], app["status"]) == (first, "running")
    assert lpam.events()[-2:] == ["alpha:install:", "alpha:start:"]
    after = lpam("plan", "--offline", "--detailed-exitcode")
    assert after.returncode == 0, after.stdout


def _rollback_reinstalling_v1(lpam: Lpam, builder: RepoBuilder,
                              git_daemon: GitDaemon) -> tuple[str, subprocess.Popen[str]]:
    """alpha v1 (whose install is slow) applied, then v2; `lpam rollback` spawned and
    caught while it reinstalls v1, whose install.sh runs until `$LPAM_ROOT/release` is
    created. Returns v1's generation and the rollback's process."""
    builder.write("libpanda-apps.yaml", "apps:\n  - name: alpha\n")
    add_app(builder, "alpha", extra={"install": held_install("v1-installing")})
    builder.commit("alpha v1: installs slowly")
    builder.push()
    lpam.desired(desired(git_daemon.url(builder.bare.name), "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    first: str = lpam.status()["app"]["generation"]
    add_app(builder, "alpha")
    builder.commit("alpha v2")
    builder.push()
    assert lpam("apply", "--yes").returncode == 0
    marker = lpam.root / "v1-installing"
    marker.unlink()
    (lpam.root / "hold").touch()  # v1's install.sh runs until the test releases it
    proc = lpam.spawn("rollback", "--yes")
    deadline = time.monotonic() + 60
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert marker.exists()
    return first, proc
