"""`mirrors:` end to end: a desired state that names its repositories as on GitHub is
fetched from a laptop's git daemon instead (here the tests' loopback daemon), as git's
`url.<base>.insteadOf` would, and nothing ever asks github.com."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo


def test_a_github_shorthand_is_fetched_from_the_mirror(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
) -> None:
    commit = apps_repo(make_repo("lab/apps"))
    lpam = Lpam(tmp_path / "root")
    lpam.desired("version: 1\nrepositories: [{repo: lab/apps}]\napp: null\n"
                 f'mirrors: {{"https://github.com/": "{git_daemon.url("")}"}}\n')
    plan = lpam("plan")
    assert plan.returncode == 0, plan.stderr
    assert f"url = {git_daemon.url('lab/apps')}" in plan.stdout
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    [repo] = lpam.status()["repositories"]
    assert repo["commit"] == commit and repo["url"] == git_daemon.url("lab/apps")


def test_without_the_mirror_the_same_document_would_go_to_github(tmp_path: Path) -> None:
    lpam = Lpam(tmp_path / "root")
    lpam.desired("version: 1\nrepositories: [{repo: lab/apps}]\napp: null\n")
    plan = lpam("plan", "--offline")
    assert plan.returncode == 0, plan.stderr
    assert "url = https://github.com/lab/apps" in plan.stdout
