"""The last apply as `lpam status` tells it, through the real CLI (issue 30 items 1, 2, 9):
a deferred apply is deferred (never killed) until an apply after it ends it, a running
apply is in progress (never cut off at the same time), and a dead apply whose script
still holds the lock is cut off — and `plan` words that script as `apply` does."""

from __future__ import annotations

import os
import signal
import subprocess
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo, desired
from tests.integration.test_bus_safety import HANG_UNTIL_RELEASED
from tests.integration.test_crash import descendants, wait_for, wait_gone
from tests.integration.test_gates import alpha_running, csv_at, gated


def last_line(text: str) -> str:
    return next(line for line in text.splitlines() if line.startswith("Last apply:"))


def test_a_deferred_apply_is_deferred_until_an_apply_with_nothing_to_do_ends_it(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon,
) -> None:
    """Item 1: exit 75 leaves `deferred` with its gate, not `in progress` with a dead pid
    (which status called killed, telling the user to resume a file that may be stale);
    the desired state in force, applied again with nothing to do, ends it."""
    url = alpha_running(lpam, git_daemon)
    csv_at(lpam, 200.0)  # driving
    other = lpam.root / "beta.yaml"
    other.write_text(gated(url, "beta", "gates: {stationary_seconds: 30}\n"))
    done = lpam("apply", "-f", str(other), "--yes")
    assert done.returncode == 75, done.stderr
    shown = lpam("status")
    line = last_line(shown.stdout)
    assert line.startswith("Last apply: deferred at") and "moving" in line, shown.stdout
    assert f"the next `lpam --root {lpam.root} apply` tries again" in line  # as it runs
    for wrong in ("cut off", "killed", "power failed", str(other), "goes on from"):
        assert wrong not in shown.stdout, shown.stdout
    status = lpam.status()
    assert status["last_apply"]["state"] == "deferred"
    assert status["last_apply"]["gates"] == ["vehicle"]
    assert "moving" in status["deferred"]["reason"]
    assert status["app"]["name"] == "alpha" and status["app"]["running"] is True

    again = lpam("apply", "--yes")  # the desired state in force: alpha, nothing to do
    assert again.returncode == 0, again.stderr
    assert lpam.events() == ["alpha:install:", "alpha:start:"]
    after = lpam("status")
    assert last_line(after.stdout).startswith("Last apply: applied at"), after.stdout
    assert "deferred" not in after.stdout and "cut off" not in after.stdout
    status = lpam.status()
    assert status["last_apply"]["state"] == "succeeded" and status["deferred"] is None


@contextmanager
def hanging_start(lpam: Lpam, make_repo: Callable[[str], RepoBuilder],
                  git_daemon: GitDaemon) -> Iterator[subprocess.Popen[str]]:
    """An apply of alpha whose start.sh (in the cutover) waits for `release`; released,
    and every process it started gone, at the end."""
    apps_repo(make_repo("apps.git"), alpha={"start": HANG_UNTIL_RELEASED})
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    apply = lpam.spawn("apply", "--yes")
    pids: list[int] = []
    try:
        wait_for(lpam.root / "start-began")
        pids = descendants(apply.pid)
        yield apply
    finally:
        (lpam.root / "release").touch()
        try:
            apply.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            apply.kill()
            apply.communicate()
        for pid in pids:
            wait_gone(pid, seconds=30)


def test_a_running_apply_is_in_progress_and_its_cutover_is_its_own(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
) -> None:
    """Item 2: never `in progress` above `Apply cut off mid-cutover`."""
    with hanging_start(lpam, make_repo, git_daemon) as apply:
        shown = lpam("status")
        assert shown.returncode == 0, shown.stderr
        assert last_line(shown.stdout).startswith("Last apply: in progress since"), \
            shown.stdout
        assert f"(pid {apply.pid})" in shown.stdout
        assert "cut off" not in shown.stdout, shown.stdout
        assert "Cutover under way since" in shown.stdout
        assert lpam.status()["last_apply"]["state"] == "in progress"
    assert apply.returncode == 0
    assert lpam.status()["last_apply"]["state"] == "succeeded"


def test_a_dead_apply_whose_script_holds_the_lock_is_cut_off_and_plan_says_so(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
) -> None:
    """Item 9: lpam is killed while its start.sh runs; the script holds the lock on. `plan`
    words it as `apply` does (a script of an apply that has ended, not "an apply in
    progress" with a dead pid), makes no one wait for a lock no apply will release, and
    says that it fell back to an offline plan; status says
    the apply was cut off, never in progress."""
    with hanging_start(lpam, make_repo, git_daemon) as apply:
        os.killpg(apply.pid, signal.SIGKILL)  # lpam; the script runs in its own group
        apply.wait(timeout=10)
        planned = lpam("plan")  # the default lock timeout
        assert planned.returncode == 0, planned.stderr
        assert "a script of an apply that has ended" in planned.stderr, planned.stderr
        # no apply will release the lock: the plan does not wait for it (not 10 s of
        # silence, nor 10 s of "waiting")
        assert "waiting up to" not in planned.stderr, planned.stderr
        assert "an apply in progress" not in planned.stderr
        assert "offline" in planned.stderr and "nothing fetched" in planned.stderr
        refused = lpam("apply", "--yes", "--lock-timeout", "0.3")
        assert refused.returncode != 0
        assert "a script of an apply that has ended" in refused.stderr, refused.stderr
        shown = lpam("status")
        assert last_line(shown.stdout).startswith("Last apply: cut off"), shown.stdout
        assert "in progress" not in shown.stdout
        assert lpam.status()["last_apply"]["state"] == "cut off"
