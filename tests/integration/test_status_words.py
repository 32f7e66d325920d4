"""Each app's status word agrees with whether it runs, through the real CLI (issue 30,
item 6): after `lpam services shutdown` no row says `running` beside Running `no`; the
plan and the status say the same of each app. A real git daemon and a real supervisord
(stopped by its pid at the end: test_services.py's `lpam` fixture)."""

from __future__ import annotations

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.test_services import lpam  # noqa: F401  (the fixture)
from tests.integration.test_several_faces import NAMES, installed, repo, three_apps  # noqa: F401


def test_after_the_service_manager_is_shut_down_no_app_is_said_to_run(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon  # noqa: F811  (the fixtures)
) -> None:
    lpam.desired(three_apps(git_daemon.url("apps.git")))
    assert lpam("apply", "--yes").returncode == 0
    assert lpam("stop", "recorder").returncode == 0
    assert lpam("services", "shutdown").returncode == 0
    table = lpam("status").stdout
    rows = {line.split()[3]: line for line in table.splitlines()[1:4]}
    for name in ("controller", "tracker"):
        cells = rows[name].split()
        assert cells[6] == "no" and cells[7] == "not", rows[name]
        assert "not running (drift: the next apply starts it)" in rows[name], rows[name]
    assert "stopped by operator" in rows["recorder"], rows["recorder"]
    assert all(" running " not in f" {r.split()[7]} " for r in rows.values()), table
    now = installed(lpam)
    assert {n: (a["running"], a["standing"]) for n, a in now.items()} == {
        "controller": (False, "not running"), "recorder": (False, "stopped by operator"),
        "tracker": (False, "not running")}
    plan = lpam("plan").stdout
    assert "start:controller@" in plan and "start:tracker@" in plan, plan
    assert "start:recorder@" not in plan, plan
