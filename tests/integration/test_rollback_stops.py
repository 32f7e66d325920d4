"""An operator's stop holds through a rollback (issue 30, item 4): `lpam rollback`
restores generations and parameters, and starts no app an operator stopped — not even one
whose parameters it changes back; its prompt and its result name each stopped app that
stays stopped and how to start it. The real CLI, a real git daemon and a real supervisord
(stopped by its pid at the end: test_services.py's `lpam` fixture)."""

from __future__ import annotations

from collections.abc import Callable

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo, desired
from tests.integration.test_services import lpam  # noqa: F401  (the fixture)
from tests.integration.test_several_faces import NAMES, installed, repo, three_apps  # noqa: F401


def test_a_rollback_starts_no_app_an_operator_stopped_and_says_so(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon  # noqa: F811  (the fixtures)
) -> None:
    url = git_daemon.url("apps.git")
    lpam.desired(three_apps(url))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(three_apps(url).replace("  - name: tracker\n",
                                         "  - name: tracker\n    params: {PACE: '2'}\n"))
    assert lpam("apply", "--yes").returncode == 0
    assert lpam("stop").returncode == 0

    back = lpam("rollback", "--yes")
    assert back.returncode == 0, back.stderr
    at = f"lpam --root {lpam.root}"  # each suggested command, as it runs (issue 30, 13)
    said = back.stdout
    kept = (f"controller, recorder, tracker were stopped by an operator (`{at} stop`) and "
            f"stay stopped after the rollback: `{at} start` (or `{at} start APP`) starts "
            "them.")
    # named before the question, and in the result
    assert said.index(kept) < said.index("Roll back to"), said
    assert said.rstrip().endswith(kept), said
    assert "start:" not in said, said
    now = installed(lpam)
    assert {n: (a["running"], a["held"], a["standing"]) for n, a in now.items()} == {
        n: (False, True, "stopped by operator") for n in NAMES}
    assert now["tracker"]["params"] == {}  # its parameters went back all the same
    started = lpam("start")
    assert started.returncode == 0, started.stderr
    assert all(a["running"] for a in installed(lpam).values())


def test_a_rollback_starts_no_stopped_app_it_installs_anew(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon  # noqa: F811  (the fixtures)
) -> None:
    """A stopped app whose generation the rollback puts back is installed, not started,
    and its operator's stop still holds it."""
    url = git_daemon.url("apps.git")
    lpam.desired(three_apps(url))
    assert lpam("apply", "--yes").returncode == 0
    repo.write("recorder/main.py", "import time\nwhile True:\n    time.sleep(0.3)\n")
    repo.commit("recorder v2")
    repo.push()
    assert lpam("apply", "--yes").returncode == 0
    assert lpam("stop", "recorder").returncode == 0
    back = lpam("rollback", "--yes")
    assert back.returncode == 0, back.stderr
    assert "install:recorder@" in back.stdout and "start:recorder@" not in back.stdout
    at = f"lpam --root {lpam.root}"  # each suggested command, as it runs (issue 30, 13)
    assert f"recorder was stopped by an operator (`{at} stop`) and stays stopped after " \
        f"the rollback: `{at} start recorder` starts it." in back.stdout, back.stdout
    recorder = installed(lpam)["recorder"]
    assert (recorder["running"], recorder["held"]) == (False, True)
    assert "recorder was stopped by `lpam stop`" in lpam("status").stdout


def test_status_names_the_hold_of_a_rollback_without_a_file(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder],  # noqa: F811  (the fixture)
    git_daemon: GitDaemon
) -> None:
    """Issue 30, item 5: after `lpam rollback` (no -f), `lpam status` names the hold —
    on its own line with how it ends, and on the app's row and line, whose status
    promises no apply's work while it holds — and the plan names it instead of saying
    the machine matches the desired state."""
    apps_repo(make_repo("apps.git"))
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha", MODE="one"))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, "alpha", MODE="two"))
    assert lpam("apply", "--yes").returncode == 0
    back = lpam("rollback", "--yes")
    assert back.returncode == 0, back.stderr
    at = f"lpam --root {lpam.root}"  # each suggested command, as it runs (issue 30, 13)
    shown = lpam("status").stdout
    assert f"Held: `{at} rollback` returned to generation" in shown, shown
    assert "it ends when the desired state last applied" in shown, shown
    row = next(line for line in shown.splitlines() if line.startswith("apps"))
    assert "held by `lpam rollback`" in row, row
    [app] = lpam.status()["installed"]
    assert app["rollback_hold"] and "held by `lpam rollback`" in app["said"]
    plan = lpam("plan").stdout
    assert f"No changes because of the holds in force: `{at} rollback` holds generation" \
        in plan and "matches the desired state" not in plan, plan
