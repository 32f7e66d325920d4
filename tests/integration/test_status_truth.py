"""What `lpam status`, `plan` and `logs` show is what runs (issue 18): the field's scenarios
replayed with the real CLI, a real git daemon and real scripts.

- a failed apply moved a checkout: the table's commit for the running app is the one it
  was installed from, and the repository says its checkout is not what runs;
- an apply cut off by a kill or a Ctrl-C shows as such, not as the apply before it;
- a hold (`lpam rollback`, `lpam stop`) holds against the desired state last applied,
  whichever file it came from, and status says how each ends;
- `lpam logs` of a script app whose unit supervisord cannot know shows its scripts' output;
- a repository without libpanda-apps.yaml is named, beside others or alone;
- a followed desired state's relative `log:` is read from the fleet repository.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, add_app, apps_repo, desired
from tests.integration.test_crash import wait_for
from tests.integration.test_fault_truth import kill_tree


def test_status_shows_the_running_commit_after_a_failed_apply_of_another(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    first = apps_repo(repo)
    add_app(repo, "beta", extra={"install": "exit 4"})
    second = repo.commit("beta cannot install")
    repo.push()
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha", ref=first))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, "beta", ref=second))
    failed = lpam("apply", "--yes")
    assert failed.returncode == 1 and "Rolled back to alpha" in failed.stderr
    shown = lpam.status()
    alpha = next(r for r in shown["apps"] if r["app"] == "alpha")
    assert (alpha["commit"], alpha["running"]) == (first[:12], True)  # what runs
    [repository] = shown["repositories"]
    assert repository["commit"] == second
    assert shown["checkouts_not_running"] == [
        {"key": repository["key"], "commit": second, "applied_commit": first}]
    table = lpam("status").stdout
    assert f"checked out at {second[:12]} by an apply that did not succeed; what runs came " \
        f"from {first[:12]}" in table, table
    assert lpam("history", "--json").returncode == 0


def test_a_repository_only_a_failed_apply_checked_out_is_not_part_of_what_runs(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    other = make_repo("other.git")
    other.write("libpanda-apps.yaml", "apps:\n  - name: gamma\n")
    add_app(other, "gamma", extra={"install": "exit 4"})
    other.commit("gamma cannot install")
    other.push()
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    text = desired(git_daemon.url("other.git"), "gamma").replace(
        "repositories:\n", f"repositories:\n  - url: {git_daemon.url('apps.git')}\n")
    lpam.desired(text)
    assert lpam("apply", "--yes").returncode == 1
    table = lpam("status").stdout
    assert "by an apply that did not succeed; nothing that runs comes from it yet" in table


def test_an_interrupted_apply_shows_as_interrupted_not_as_the_one_before(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"), beta={
        "install": 'touch "$LPAM_ROOT/installing"; sleep 30'})
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    assert "Last apply: applied" in lpam("status").stdout
    lpam.desired(desired(url, "beta"))
    for sig, word in ((signal.SIGKILL, "cut off"), (signal.SIGINT, "interrupted")):
        (lpam.root / "installing").unlink(missing_ok=True)
        proc = lpam.spawn("apply", "--yes")
        wait_for(lpam.root / "installing")
        if sig is signal.SIGKILL:
            kill_tree(proc.pid)  # lpam and its script: a power cut, as far as it goes
        else:
            os.kill(proc.pid, sig)
        proc.communicate(timeout=60)
        shown = lpam.status()["last_apply"]
        assert shown["result"] == ("in progress" if sig is signal.SIGKILL else "interrupted")
        line = next(line for line in lpam("status").stdout.splitlines()
                    if line.startswith("Last apply:"))
        assert word in line and " apply` goes on from where it stood" in line, line


def test_a_rollback_holds_against_the_file_last_applied_and_status_says_how_it_ends(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    apps_repo(repo)
    url = git_daemon.url("apps.git")
    mine = lpam.root / "mine.yaml"
    mine.parent.mkdir(parents=True, exist_ok=True)
    mine.write_text(desired(url, "alpha", MODE="one"))
    assert lpam("apply", "-f", str(mine), "--yes").returncode == 0
    mine.write_text(desired(url, "alpha", MODE="two"))
    assert lpam("apply", "-f", str(mine), "--yes").returncode == 0
    add_app(repo, "alpha", extra={"start": "echo v2"})
    repo.commit("alpha v2")
    repo.push()
    assert lpam("apply", "-f", str(mine), "--yes").returncode == 0
    back = lpam("rollback", "--yes")  # no -f, and no default file: it holds all the same
    assert back.returncode == 0, back.stderr
    plan = lpam("plan", "-f", str(mine), "--detailed-exitcode")
    assert plan.returncode == 0 and "held by `lpam rollback`" in plan.stdout, plan.stdout
    holds = lpam.status()["holds"]
    assert [h["kind"] for h in holds] == ["rollback"] and str(mine) in holds[0]["ends"]
    assert (f"Held: `lpam --root {lpam.root} rollback` returned to generation"
            in lpam("status").stdout)  # spelled for the root it acts on (issue 30, 13)
    released = lpam("apply", "-f", str(mine), "--yes", "--release")
    assert released.returncode == 0 and "Released the hold" in released.stdout
    assert lpam.status()["holds"] == []


def test_an_operators_stop_holds_against_the_desired_state_and_ends_when_it_changes(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    other = make_repo("other.git")
    other.write("libpanda-apps.yaml", "apps: []\n")
    other.commit("no apps")
    other.push()
    url = git_daemon.url("apps.git")
    mine = lpam.root / "mine.yaml"
    mine.parent.mkdir(parents=True, exist_ok=True)
    mine.write_text(desired(url, "alpha"))
    assert lpam("apply", "-f", str(mine), "--yes").returncode == 0
    assert lpam("stop").returncode == 0
    [hold] = lpam.status()["holds"]
    # spelled for this sandbox, as the table is: `lpam --root R start`
    assert hold["kind"] == "operator stop" and "start`" in hold["ends"]
    assert f"--root {lpam.root}" in hold["ends"], hold["ends"]
    assert lpam("plan", "-f", str(mine), "--detailed-exitcode").returncode == 0
    # a change of the desired state (not of the app) ends the stop
    mine.write_text(desired(url, "alpha").replace(
        "repositories:\n", f"repositories:\n  - url: {git_daemon.url('other.git')}\n"))
    plan = lpam("plan", "-f", str(mine))
    assert "the operator's stop of alpha ends" in plan.stderr, plan.stderr
    assert "start:alpha@" in plan.stdout
    assert lpam("apply", "-f", str(mine), "--yes").returncode == 0
    assert lpam.status()["app"]["running"] is True and lpam.status()["holds"] == []


def test_logs_of_a_script_app_whose_unit_supervisord_cannot_know(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"), alpha={"start": 'echo "alpha started in mode $MODE"'})
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", MODE="calm"))
    assert lpam("apply", "--yes").returncode == 0
    shown = lpam("logs")
    assert shown.returncode == 0, shown.stderr
    assert "alpha started in mode calm" in shown.stdout
    assert "== alpha: bash start.sh" in shown.stdout
    assert "unit can is not known to supervisor" in shown.stderr
    assert "journalctl -u can" in shown.stderr
    follow = lpam("logs", "-f")
    assert follow.returncode == 1 and "cannot follow" in follow.stderr


def test_logs_with_nothing_known_is_an_error_saying_where_to_look(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    for log in (lpam.root / "var/log/lpam").glob("*.log"):
        log.unlink()
    silent = lpam("logs")
    assert silent.returncode == 1 and "no output of alpha is known" in silent.stderr


def test_a_repository_without_a_catalog_is_named(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    bare = make_repo("bare.git")
    bare.write("README.md", "no apps here\n")
    bare.commit("just a readme")
    bare.push()
    both = desired(git_daemon.url("apps.git"), "alpha").replace(
        "repositories:\n", f"repositories:\n  - url: {git_daemon.url('bare.git')}\n")
    lpam.desired(both)
    plan = lpam("plan")
    assert plan.returncode == 0, plan.stderr
    assert "has no libpanda-apps.yaml at" in plan.stdout and "offers no apps" in plan.stdout
    lpam.desired(desired(git_daemon.url("bare.git"), "alpha"))
    alone = lpam("plan")
    assert alone.returncode == 1
    assert "has no libpanda-apps.yaml" in alone.stderr and "(available: none)" in alone.stderr


def test_a_followed_desired_states_relative_log_is_read_from_the_fleet_repository(
    make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon, apps: str, car: Lpam
) -> None:
    """vehicles/rav4-07.yaml names `log: drives/parked.log` (vehicles/drives/ in the fleet
    repository); the gate reads it from the repository at that revision (a car parked
    200 s) and lets the cutover through."""
    fleet = make_repo("fleet.git")
    now = time.time()
    frames = "".join(f"({now - 200 + i * 0.1:.6f}) can0 0B4#0000000000000000\n"
                     for i in range(2000))
    text = desired("../apps.git", "alpha") + (
        "vehicle:\n  source: {log: drives/parked.log}\n  stale_seconds: 3600\n"
        "gates:\n  stationary_seconds: 60\n")
    fleet.commit("a parked car", {"vehicles/rav4-07.yaml": text,
                                  "vehicles/drives/parked.log": frames})
    fleet.push()
    done = car("sync")
    assert done.returncode == 0, done.stderr
    assert "deferred" not in done.stdout + done.stderr
    assert car.status()["app"]["name"] == "alpha"
    stop = car("stop")  # an operator's command obeys the gates of the applied revision
    assert stop.returncode == 0, stop.stderr
    assert [h["kind"] for h in car.status()["holds"]] == ["operator stop"]
    copies = list((car.root / "var/lib/lpam/agent-files").rglob("parked.log"))
    assert len(copies) == 1 and Path(copies[0]).read_text() == frames
