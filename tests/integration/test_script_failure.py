"""A failed script shows what it said: the field trial's install failure named only the
apply log's path, while a failed health check shows the unit's last lines. The real CLI, a
real git daemon on 127.0.0.1, real bash scripts."""

from __future__ import annotations

from collections.abc import Callable

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo, desired

LOUD = "echo 'alpha started fine'"
# 30 lines, then the reason, then the failure: the user reads the last 20 of them
FAILING = 'for i in $(seq 1 30); do echo "compiling part $i"; done\n' \
    "echo 'E: Unable to locate package libfoo-dev' >&2\nexit 4"


def test_a_failed_install_shows_the_last_lines_of_its_script_alone(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"), alpha={"start": LOUD}, beta={"install": FAILING})
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, "beta"))
    done = lpam("apply", "--yes")
    assert done.returncode == 1
    lines = done.stderr.splitlines()
    assert "  | install.sh: E: Unable to locate package libfoo-dev" in lines, done.stderr
    assert "  | install.sh: compiling part 30" in lines
    assert "  | install.sh: compiling part 12" in lines
    assert "  | install.sh: compiling part 11" not in lines  # 20 lines, the last ones
    # only this script's own output: not what alpha's scripts said before it
    assert "alpha started fine" not in done.stderr
    assert "Traceback" not in done.stderr
