"""What lpam says after a fault is what runs: the real CLI, a real supervisord, real apps.

Every app here holds the CAN bus as the field's apps do — modelled by an exclusive `flock`
on `$LPAM_ROOT/bus.lock` — and a copy that finds the bus taken writes `collisions.log`:
two apps on the bus. `lpam` is killed (SIGKILL of its whole session: it and any script)
at a step of a switch to an app that fails its health check, of the automatic rollback,
of an operator's stop; supervisord is killed with `kill -9`; the journal and the state
record are made unwritable. After each, `status`, `plan` and `apply` must tell the truth
and the car must run exactly the app they name. Every test stops its supervisord and
every app process by pid at the end.
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from tests.contract.test_services import alive, wait_for
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo, desired, processes

BUS = """\
import fcntl, os, sys, time
root, app = os.environ["LPAM_ROOT"], os.environ["LPAM_APP"]
fd = os.open(os.path.join(root, "bus.lock"), os.O_RDWR | os.O_CREAT)
try:
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
except OSError:
    with open(os.path.join(root, "collisions.log"), "a") as log:
        log.write(f"{app} {os.getpid()}\\n")
    sys.exit(1)
print(app, "holds the bus", flush=True)
while True:
    time.sleep(0.1)
"""

CATALOG = """\
apps:
  - name: steady
    command: [python3, -u, bus.py]
    health: {settle_seconds: 1}
  - name: other
    command: [python3, -u, bus.py]
    health: {settle_seconds: 1}
  - name: failing
    command: [python3, -u, bus.py]
    health: {settle_seconds: 1.5, command: [./healthy.sh]}
"""


@pytest.fixture
def lpam(tmp_path: Path) -> Iterator[Lpam]:
    runner = Lpam(tmp_path / "root")
    try:
        yield runner
    finally:
        shutdown(Layout(runner.root))
        for pid in processes(runner.root):  # whatever a killed supervisord left behind
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


@pytest.fixture
def url(make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon) -> str:
    builder = make_repo("bus.git")
    builder.write("libpanda-apps.yaml", CATALOG)
    for app in ("steady", "other", "failing"):
        builder.write(f"{app}/bus.py", BUS)
    builder.write("failing/healthy.sh", "#!/bin/sh\necho 'no data from the bus'\nexit 1\n",
                  executable=True)
    builder.commit("apps that hold the bus")
    builder.push()
    return git_daemon.url("bus.git")


def bus_holders(root: Path) -> list[int]:
    """The live app processes of this root: one per copy of an app (apps.py `processes`)."""
    return processes(root, b"bus.py")


def apps_running(root: Path) -> list[str]:
    names = []
    for pid in bus_holders(root):
        with contextlib.suppress(OSError):
            env = dict(item.split(b"=", 1) for item in
                       Path(f"/proc/{pid}/environ").read_bytes().split(b"\0") if b"=" in item)
            names.append(env[b"LPAM_APP"].decode())
    return sorted(names)


def settled(root: Path, seconds: float = 15) -> list[str]:
    """The apps running once the set stops changing (supervisord restarts take a moment)."""
    deadline = time.monotonic() + seconds
    last = apps_running(root)
    while time.monotonic() < deadline:
        time.sleep(0.3)
        now = apps_running(root)
        if now == last:
            return now
        last = now
    return last


def no_collisions(root: Path) -> None:
    log = root / "collisions.log"
    assert not log.exists(), f"two apps on the bus: {log.read_text()}"


def journal(root: Path) -> list[dict[str, Any]]:
    path = root / "var/lib/lpam/journal.jsonl"
    events = []
    with contextlib.suppress(OSError):
        for line in path.read_text().splitlines():
            with contextlib.suppress(ValueError):
                events.append(json.loads(line))
    return events


def kill_when(lpam: Lpam, proc: Any, began: Callable[[str], bool], seconds: float = 60) -> str:
    """SIGKILL lpam's whole session as soon as the journal shows a step `began` begin."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        for event in journal(lpam.root):
            step = event.get("step")
            if event.get("event") == "begin" and isinstance(step, str) and began(step):
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
                return step
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.005)
    raise AssertionError("the step never began")


def supervisord_pid(root: Path) -> int:
    return int((root / "run/lpam/supervisord.pid").read_text())


def kill_9_supervisord(root: Path) -> None:
    """`kill -9` of this root's supervisord, returning once it is dead (or a zombie that
    init has not reaped yet); the programs it ran live on."""
    pid = supervisord_pid(root)
    os.kill(pid, signal.SIGKILL)
    assert wait_for(lambda: not alive(pid), 10), f"supervisord {pid} survived kill -9"


def running_steady(lpam: Lpam, url: str) -> None:
    lpam.desired(desired(url, "steady"))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert settled(lpam.root) == ["steady"]


@pytest.mark.parametrize("kind", ["install", "start", "verify"])
def test_a_kill_between_install_and_the_end_of_verify_never_skips_the_health_check(
    lpam: Lpam, url: str, kind: str
) -> None:
    running_steady(lpam, url)
    lpam.desired(desired(url, "failing"))
    proc = lpam.spawn("apply", "--yes")
    kill_when(lpam, proc, lambda step: step.startswith(f"{kind}:failing@"))
    assert "Apply cut off mid-cutover" in lpam("status").stdout
    plan = lpam("plan")
    assert "verify:failing@" in plan.stdout, plan.stdout + plan.stderr
    done = lpam("apply", "--yes")
    assert done.returncode == 3, done.stdout + done.stderr  # never "Apply complete"
    assert "health check" in done.stderr and "Rolled back to steady" in done.stderr
    status = lpam.status()
    assert (status["app"]["name"], status["app"]["running"]) == ("steady", True)
    assert status["last_apply"]["result"] == "rolled back" and status["cutover"] is None
    history = json.loads(lpam("history", "--json").stdout)
    assert [(h["app"], h["result"]) for h in history] == [
        ("steady", "applied"), ("failing", "rolled back")]
    assert settled(lpam.root) == ["steady"]
    no_collisions(lpam.root)


@pytest.mark.parametrize("kind", ["stop", "uninstall", "install", "start"])
def test_a_kill_during_the_automatic_rollback_is_finished_by_the_next_apply(
    lpam: Lpam, url: str, kind: str
) -> None:
    running_steady(lpam, url)
    lpam.desired(desired(url, "failing"))
    proc = lpam.spawn("apply", "--yes")
    kill_when(lpam, proc, lambda step: step.startswith(f"rollback/{kind}:"))
    status = lpam("status")
    assert "Rollback cut off: failing failed" in status.stdout, status.stdout
    plan = lpam("plan")
    assert "the rollback to steady after failing failed" in plan.stdout, plan.stdout
    done = lpam("apply", "--yes")
    assert done.returncode == 3, done.stdout + done.stderr
    assert "cut off by a fault; this run finished it: rolled back to steady" in done.stderr
    status_json = lpam.status()
    assert (status_json["app"]["name"], status_json["app"]["running"]) == ("steady", True)
    assert status_json["last_apply"]["result"] == "rolled back"
    history = json.loads(lpam("history", "--json").stdout)
    assert [(h["app"], h["result"]) for h in history][-1] == ("failing", "rolled back")
    assert settled(lpam.root) == ["steady"]
    no_collisions(lpam.root)
    # the failure stays: the next apply tries the desired app again and rolls it back again
    again = lpam("apply", "--yes")
    assert again.returncode == 3 and "Rolled back to steady" in again.stderr
    assert settled(lpam.root) == ["steady"]
    no_collisions(lpam.root)


def test_kill_9_of_supervisord_is_seen_and_never_gives_a_second_copy(
    lpam: Lpam, url: str
) -> None:
    running_steady(lpam, url)
    [orphan] = bus_holders(lpam.root)
    kill_9_supervisord(lpam.root)
    status = lpam.status()
    assert status["app"]["running"] is True  # it does run, unsupervised
    assert status["app"]["unit"]["supervised"] is False
    assert status["app"]["unit"]["pid"] == orphan
    assert "its service manager died" in lpam("status").stdout
    plan = lpam("plan", "--detailed-exitcode")
    assert plan.returncode == 2 and "runs without its service manager" in plan.stdout
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert settled(lpam.root) == ["steady"]
    [copy] = bus_holders(lpam.root)
    assert copy != orphan  # the orphan was ended, one copy runs under the new supervisord
    assert lpam.status()["app"]["unit"]["supervised"] is True
    assert lpam("plan", "--detailed-exitcode").returncode == 0
    no_collisions(lpam.root)


@pytest.mark.parametrize("command", [("stop",), ("services", "shutdown")])
def test_stop_and_shutdown_end_what_a_killed_supervisord_left_running(
    lpam: Lpam, url: str, command: tuple[str, ...]
) -> None:
    running_steady(lpam, url)
    kill_9_supervisord(lpam.root)
    done = lpam(*command)
    assert done.returncode == 0, done.stderr
    assert "No supervisord was running" not in done.stdout
    assert settled(lpam.root) == []
    if command == ("stop",):
        assert lpam.status()["app"]["running"] is False
        assert lpam("plan", "--detailed-exitcode").returncode == 0  # the stop holds


def test_kill_9_of_supervisord_during_a_switch_never_gives_two_apps(
    lpam: Lpam, url: str
) -> None:
    running_steady(lpam, url)
    lpam.desired(desired(url, "other"))
    proc = lpam.spawn("apply", "--yes")
    deadline = time.monotonic() + 60
    while not any(e.get("step", "").startswith("stop:steady") for e in journal(lpam.root)
                  if isinstance(e.get("step"), str)):
        assert time.monotonic() < deadline
        time.sleep(0.005)
    os.kill(supervisord_pid(lpam.root), signal.SIGKILL)
    proc.communicate(timeout=120)
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert settled(lpam.root) == ["other"]
    assert lpam.status()["app"]["name"] == "other"
    no_collisions(lpam.root)


def test_an_operators_stop_cut_off_is_carried_out_not_undone(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"), alpha={
        "stop": 'if [ -e "$LPAM_ROOT/hang-stop" ]; then touch "$LPAM_ROOT/stopping"; sleep 60; fi'})
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    (lpam.root / "hang-stop").touch()
    proc = lpam.spawn("stop")
    deadline = time.monotonic() + 30
    while not (lpam.root / "stopping").exists():
        assert time.monotonic() < deadline
        time.sleep(0.02)
    kill_tree(proc.pid)
    (lpam.root / "hang-stop").unlink()
    status = lpam("status")
    assert "an operator's stop did not finish" in status.stdout, status.stdout
    plan = lpam("plan")
    assert "stop:alpha@" in plan.stdout and "start:alpha@" not in plan.stdout, plan.stdout
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.events()[-1] == "alpha:stop:"  # stopped, and not started again
    app = lpam.status()["app"]
    assert (app["status"], app["held"]) == ("installed", True)
    assert lpam("plan", "--detailed-exitcode").returncode == 0


def kill_tree(pid: int) -> None:
    """SIGKILL lpam and every process below it (the script runs in its own group)."""
    from tests.integration.test_crash import descendants, wait_gone

    victims = [pid, *descendants(pid)]
    for victim in victims:
        with contextlib.suppress(OSError):
            os.kill(victim, signal.SIGKILL)
    for victim in victims:
        wait_gone(victim)


def test_a_journal_made_unwritable_mid_apply_lets_the_switch_finish(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    journal_path = "$LPAM_ROOT/var/lib/lpam/journal.jsonl"
    apps_repo(make_repo("apps.git"),
              beta={"install": f'rm -f "{journal_path}"; mkdir "{journal_path}"'})
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, "beta"))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("journal could not be written") == 1, done.stdout
    app = lpam.status()["app"]
    assert (app["name"], app["running"]) == ("beta", True)
    assert lpam.events()[-4:] == ["alpha:stop:", "alpha:uninstall:", "beta:install:",
                                  "beta:start:"]


def test_a_full_disk_mid_apply_stops_where_the_record_stands_and_says_so(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    """From beta's start.sh on, lpam can write no file (RLIMIT_FSIZE, as a full disk):
    the record cannot take start.sh's outcome, lpam does nothing more and says what the
    record shows; once it can write again, the next apply converges."""
    apps_repo(make_repo("apps.git"), beta={"start": (
        'touch "$LPAM_ROOT/start-began"; '
        'for _ in $(seq 200); do [ -e "$LPAM_ROOT/disk-full" ] && break; sleep 0.05; done')})
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, "beta"))
    proc = lpam.spawn("apply", "--yes")
    deadline = time.monotonic() + 60
    while not (lpam.root / "start-began").exists():
        assert time.monotonic() < deadline
        time.sleep(0.02)
    resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (1, 1))  # no write past one byte
    (lpam.root / "disk-full").touch()
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, out + err
    assert "cannot write the state record" in err and "The record shows beta" in err, err
    assert "internal error" not in err and "Traceback" not in err
    app = lpam.status()["app"]
    assert app["name"] == "beta"  # what the record says is what the scripts did
    assert lpam.events()[-1] == "beta:start:"  # nothing ran after the failed write
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    app = lpam.status()["app"]
    assert (app["name"], app["running"], app["good"]) == ("beta", True, True)
    assert lpam.events().count("beta:start:") == 1  # it had finished: not run twice
