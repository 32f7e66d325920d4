"""`lpam status` shows what was committed, never what a link points at; a damaged
journal blocks neither a plan nor an apply.

A repository is not trusted: an app folder can hold `service -> /etc/shadow`, or be a
link to a directory outside the repository. Status used to print such a file for apps
installed or not; the secret here stands for /etc/shadow. The journal only says which
step an interrupted apply was in, so damage to it must never stop the vehicle's updates.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from reconciler.base.layout import Layout
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, add_app, apps_repo, desired

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
    assert (rows["alpha"]["status"], rows["beta"]["status"]) == ("running", None)


def test_status_shows_what_was_committed_not_what_is_on_disk_now(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon, secret: Path
) -> None:
    """Files replaced by links after the apply (in the checkout, for the app never
    installed, and in the installed generation) are not read: status reads git objects."""
    apps_repo(make_repo("apps.git"))
    lpam = Lpam(tmp_path / "root")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    shown = lpam.status()
    layout = Layout(lpam.root)
    checkout = layout.repository_dir(shown["repositories"][0]["key"])
    generation = layout.generation_dir("alpha", shown["app"]["generation"])
    for folder in (checkout / "alpha", checkout / "beta", generation):
        for name in ("service", "description.txt"):
            (folder / name).unlink()
            (folder / name).symlink_to(secret / name)
    for args in (("status",), ("status", "--json")):
        again = lpam(*args)
        assert again.returncode == 0, again.stderr
        assert "secret-hash" not in again.stdout + again.stderr
        assert "the alpha app" in again.stdout and "the beta app" in again.stdout
    rows = {r["app"]: r for r in lpam.status()["apps"]}
    assert [rows[a]["service"] for a in ("alpha", "beta")] == ["can", "can"]
    assert rows["alpha"]["status"] == "running"
    assert "running" in lpam("status").stdout.splitlines()[1].split()


def test_a_damaged_journal_blocks_neither_plan_nor_apply(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    lpam = Lpam(tmp_path / "root")
    journal = Layout(lpam.root).journal
    journal.mkdir(parents=True)
    (journal / "whatever").write_text("kept\n")
    for app, damage in (("alpha", None), ("beta", b"\xff\n" + b"[" * 100_000 + b"\n")):
        if damage is not None:
            journal.write_bytes(damage)
        lpam.desired(desired(git_daemon.url("apps.git"), app))
        plan = lpam("plan")
        assert plan.returncode == 0, plan.stderr
        assert "interrupted" not in plan.stdout + plan.stderr
        done = lpam("apply", "--yes")
        assert done.returncode == 0, done.stderr
        assert ("moved it to" in done.stdout) is (damage is None)
        assert lpam.status()["app"]["status"] == "running"
    assert lpam.events() == ["alpha:install:", "alpha:start:", "alpha:stop:",
                             "alpha:uninstall:", "beta:install:", "beta:start:"]
    [aside] = journal.parent.glob("journal.jsonl.damaged-*")
    assert (aside / "whatever").read_text() == "kept\n"
