"""Power cuts and races: SIGKILL of the whole process tree in the middle of the cutover,
and two applies at once. The machine must converge without repeating finished steps, and
the CAN hardware must never get two apps."""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo, desired

HANG_ONCE = """\
if [ ! -e "$LPAM_ROOT/killed-once" ]; then
  touch "$LPAM_ROOT/install-started"
  sleep 60
fi"""


def descendants(pid: int) -> list[int]:
    """Every process below `pid`, from /proc (the scripts run in their own process group)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def wait_for(path: Path, seconds: float = 60) -> None:
    deadline = time.monotonic() + seconds
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.05)


def wait_gone(pid: int, seconds: float = 10) -> None:
    deadline = time.monotonic() + seconds
    while True:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return
        if state in ("Z", "X"):
            return
        assert time.monotonic() < deadline, f"process {pid} survived SIGKILL"
        time.sleep(0.05)


def test_sigkill_during_cutover_then_apply_converges(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"), beta={"install": HANG_ONCE})
    lpam = Lpam(tmp_path / "root")
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, "beta"))
    proc = lpam.spawn("apply", "--yes")
    wait_for(lpam.root / "install-started")
    victims = [proc.pid, *descendants(proc.pid)]
    for pid in victims:
        os.kill(pid, signal.SIGKILL)
    proc.wait(timeout=30)
    for pid in victims[1:]:  # the killed script and its sleep are gone too
        wait_gone(pid)
    assert proc.returncode == -signal.SIGKILL
    # alpha is uninstalled; the record says beta's install.sh may have been cut off
    record = json.loads((lpam.root / "var/lib/lpam/state.json").read_text())
    [app] = record["apps"]  # the record lists the installed apps (version 5 on)
    assert (app["name"], app["status"]) == ("beta", "installing")
    (lpam.root / "killed-once").touch()
    again = lpam("apply", "--yes")
    assert again.returncode == 0, again.stderr
    # killed, not interrupted: the note says as much as it knows, as status says cut off
    assert "stopped during install:beta@" in again.stderr
    assert "interrupted" not in again.stderr, again.stderr
    assert lpam.events() == [
        "alpha:install:", "alpha:start:",          # first apply
        "alpha:stop:", "alpha:uninstall:",         # cutover, before the kill: not repeated
        "beta:install:",                           # killed in the middle
        "beta:install:", "beta:start:",            # resumed: only the unfinished work
    ]
    status = lpam.status()
    assert status["app"]["name"] == "beta" and status["app"]["running"] is True
    assert lpam("plan", "--detailed-exitcode").returncode == 0


def test_two_concurrent_applies_install_once(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"), alpha={"install": "sleep 1"})
    lpam = Lpam(tmp_path / "root")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    first = lpam.spawn("apply", "--yes", "--lock-timeout", "60")
    second = lpam.spawn("apply", "--yes", "--lock-timeout", "60")
    outputs = [p.communicate(timeout=120) for p in (first, second)]
    assert [first.returncode, second.returncode] == [0, 0], outputs
    assert lpam.events() == ["alpha:install:", "alpha:start:"]
    assert sum("No changes" in out for out, _ in outputs) == 1


def test_second_apply_fails_clearly_when_the_lock_is_held(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"), alpha={"install": (  # holds the lock until released
        'touch "$LPAM_ROOT/in-install"\n'
        'for _ in $(seq 600); do [ -e "$LPAM_ROOT/release" ] && break; sleep 0.05; done')})
    lpam = Lpam(tmp_path / "root")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    first = lpam.spawn("apply", "--yes")
    try:
        wait_for(lpam.root / "in-install")
        second = lpam("apply", "--yes", "--lock-timeout", "0.5")
    finally:
        (lpam.root / "release").touch()
    assert second.returncode == 1
    assert "another lpam apply" in second.stderr and "--lock-timeout" in second.stderr
    first.communicate(timeout=60)
    assert first.returncode == 0
    assert lpam.events() == ["alpha:install:", "alpha:start:"]
