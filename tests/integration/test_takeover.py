"""Taking over a vehicle that used LPAM, in place (issue 18): `import-lpam` pins the
commit LPAM's clone holds; an app LPAM installed from that very commit is adopted as it
runs — no script, no restart, no recording interrupted — and after later switches every
app the repositories offer keeps its folder in /etc/libpanda.d/apps/ for the old tool.
The real CLI, a real git daemon, real scripts that leave a trace."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo


def lpam_vehicle(lpam: Lpam, repo: RepoBuilder, commit: str, *, edited: bool = False) -> Path:
    """/etc/libpanda.d as LPAM left it: its manifest (current: alpha), its clone of the
    repository at `commit`, and alpha's folder copied out of that commit (`edited`: one
    file changed since, as a hand edit on the car would)."""
    etc = lpam.root / "etc/libpanda.d"
    clone = etc / "apps-repositories/lab/apps/.git"
    (clone / "refs/heads").mkdir(parents=True)
    (clone / "HEAD").write_text("ref: refs/heads/main\n")
    (clone / "refs/heads/main").write_text(commit + "\n")
    shutil.copytree(repo.work / "alpha", etc / "apps/alpha")
    if edited:
        (etc / "apps/alpha/description.txt").write_text("edited on the car\n")
    (etc / "app-manifest.yaml").write_text(
        "version: 0.0\nrepositories:\n  lab/apps: {branch: main}\ncurrent: alpha\n")
    return etc


def imported(lpam: Lpam, url: str) -> str:
    done = lpam("import-lpam", "-o", str(lpam.root / "etc/lpam/desired-state.yaml"))
    assert done.returncode == 0, done.stderr
    text = (lpam.root / "etc/lpam/desired-state.yaml").read_text()
    # the test's repository is served by the loopback daemon, not GitHub
    text = text.replace("repo: lab/apps", f"url: {url}")
    (lpam.root / "etc/lpam/desired-state.yaml").write_text(text)
    return text


def test_import_pins_the_commit_lpams_clone_holds(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    commit = apps_repo(repo)
    lpam_vehicle(lpam, repo, commit)
    done = lpam("import-lpam")
    assert done.returncode == 0, done.stderr
    assert f"ref: {commit}  # main: where LPAM's clone was" in done.stdout, done.stdout


def test_an_app_lpam_installed_from_the_desired_commit_is_adopted_without_a_restart(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    commit = apps_repo(repo)
    etc = lpam_vehicle(lpam, repo, commit)
    imported(lpam, git_daemon.url("apps.git"))
    plan = lpam("plan")
    assert "adopted in place" in plan.stdout, plan.stdout
    assert "stray." not in plan.stdout and "start:" not in plan.stdout
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert lpam.events() == []  # no script ran: nothing was stopped, reinstalled, restarted
    app = lpam.status()["app"]
    assert (app["name"], app["commit"], app["status"]) == ("alpha", commit, "running")
    assert (etc / "apps/alpha").is_symlink()  # the generation, same files as LPAM's copy
    assert (lpam.root / "var/lib/lpam/replaced/alpha").is_dir()  # LPAM's kept aside
    assert "current: alpha" in (etc / "app-manifest.yaml").read_text()
    assert lpam("plan", "--detailed-exitcode").returncode == 0


def test_status_says_what_plan_does_with_the_app_lpam_installed(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    """Status derives what an apply does with LPAM's app from the observation plan uses
    (issue 30, item 3): adopted in place when plan adopts it, stopped and uninstalled when
    plan takes it over, and not guessed before the desired commit is fetched. The apply
    that adopts it says nothing of scripts, for none ran (item 14)."""
    repo = make_repo("apps.git")
    commit = apps_repo(repo)
    lpam_vehicle(lpam, repo, commit)
    imported(lpam, git_daemon.url("apps.git"))
    at = f"lpam --root {lpam.root}"  # each suggested command, as it runs (issue 30, 13)
    before = lpam("status").stdout
    assert f"`{at} apply` stops and uninstalls it before" not in before, before
    assert "stops and uninstalls it before installing" not in before, before
    assert f"known once `{at} plan` has fetched the desired commits" in before, before
    assert "adopted in place" in lpam("plan").stdout
    shown = lpam("status").stdout
    assert f"Installed by LPAM: alpha, the desired app alpha as it is: `{at} apply` adopts " \
        "it in place (no script runs, it is not restarted)." in shown, shown
    assert "stops and uninstalls" not in shown, shown
    [stray] = lpam.status()["strays"]
    assert (stray["fate"], stray["adopted_as"]) == ("adopted", "alpha")
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert "reported" not in done.stdout and "alpha unverified: recorded running" in \
        done.stdout, done.stdout
    assert lpam.events() == []


def test_status_says_an_app_lpam_installed_differently_is_stopped_and_uninstalled(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    commit = apps_repo(repo)
    lpam_vehicle(lpam, repo, commit, edited=True)
    imported(lpam, git_daemon.url("apps.git"))
    assert "adopted" not in lpam("plan").stdout
    shown = lpam("status").stdout
    at = f"lpam --root {lpam.root}"  # each suggested command, as it runs (issue 30, 13)
    assert f"`{at} apply` stops and uninstalls it before installing any app." in shown, shown
    assert lpam.status()["strays"][0]["fate"] == "replaced"


def test_an_app_lpam_installed_differently_is_taken_over_with_its_scripts(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    commit = apps_repo(repo)
    lpam_vehicle(lpam, repo, commit, edited=True)
    imported(lpam, git_daemon.url("apps.git"))
    assert "adopted" not in lpam("plan").stdout
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.events() == ["alpha:stop:", "alpha:uninstall:", "alpha:install:",
                             "alpha:start:"]


def test_after_switches_every_offered_app_keeps_its_folder_for_the_old_tool(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    commit = apps_repo(repo)
    etc = lpam_vehicle(lpam, repo, commit)
    text = imported(lpam, git_daemon.url("apps.git"))
    assert lpam("apply", "--yes").returncode == 0
    desired = lpam.root / "etc/lpam/desired-state.yaml"
    desired.write_text(text.replace("app: alpha", "app: beta"))
    assert lpam("apply", "--yes").returncode == 0
    alpha, beta = etc / "apps/alpha", etc / "apps/beta"
    assert beta.is_symlink()  # the installed app: its generation
    assert alpha.is_dir() and not alpha.is_symlink()  # kept, as LPAM's -d and -i read it
    assert (alpha / "description.txt").read_text() == "the alpha app\n"
    desired.write_text(text)  # and back: beta's folder stays, alpha is the link again
    assert lpam("apply", "--yes").returncode == 0
    assert alpha.is_symlink() and beta.is_dir() and not beta.is_symlink()
    assert (beta / "start.sh").is_file()
    assert not list((lpam.root / "var/lib/lpam/replaced").glob("alpha.*"))  # no pile-up
