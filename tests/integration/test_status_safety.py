"""`lpam status` shows what was committed, never what a link points at.

A repository is not trusted: an app folder can hold `service -> /etc/shadow`, or be a
link to a directory outside the repository. Status used to print such a file for apps
installed or not; the secret here stands for /etc/shadow.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, add_app, desired

SECRET = "root:$6$secret-hash:19000:0:99999:7:::"


@pytest.fixture
def secret(tmp_path: Path) -> Path:
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "service").write_text(SECRET + "\n")
    (outside / "description.txt").write_text(SECRET + "\n")
    return outside


def test_status_never_prints_a_file_through_a_link(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon, secret: Path
) -> None:
    repo = make_repo("apps.git")
    repo.write("libpanda-apps.yaml",
               "apps:\n  - name: alpha\n  - name: beta\n  - name: gamma\n")
    add_app(repo, "alpha")
    (repo.work / "alpha/service").unlink()
    repo.symlink("alpha/service", str(secret / "service"))  # installed below
    add_app(repo, "beta")
    (repo.work / "beta/description.txt").unlink()
    repo.symlink("beta/description.txt", str(secret / "description.txt"))  # never installed
    repo.symlink("gamma", str(secret))  # an app folder that is a link out of the repository
    repo.commit("links out")
    repo.push()
    lpam = Lpam(tmp_path / "root")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    for args in (("status",), ("status", "--json")):
        shown = lpam(*args)
        assert shown.returncode == 0, shown.stderr
        assert "secret-hash" not in shown.stdout + shown.stderr
        assert "alpha" in shown.stdout and "beta" in shown.stdout
    app = lpam.status()["app"]
    assert app["name"] == "alpha" and app["status"] == "running"
    rows = {r["app"]: r for r in lpam.status()["apps"]}
    assert rows["beta"]["description"] == ""  # not the link's target
    assert rows["alpha"]["description"] == "the alpha app"  # regular files still shown
