"""plan / apply / status end to end: the real CLI, a real git daemon on 127.0.0.1, real
bash scripts. Each test asserts what an operator would check: the exit code, what the
status says, and the order in which the app scripts ran."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, add_app, apps_repo, desired


def test_first_apply_from_empty_installs_and_starts(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", MODE="fast"))
    plan = lpam("plan", "--detailed-exitcode")
    assert plan.returncode == 2, plan.stderr
    assert "+ repository.apps" in plan.stdout and "+ app.alpha: install alpha" in plan.stdout
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert lpam.events() == ["alpha:install:fast", "alpha:start:fast"]
    status = lpam.status()
    head = repo.rev("main")
    assert status["app"]["name"] == "alpha" and status["app"]["commit"] == head
    assert status["repositories"] == [
        {"key": "apps", "url": git_daemon.url("apps.git"), "ref": None, "commit": head}]
    table = lpam("status").stdout
    assert "alpha" in table and "the beta app" in table and "yes" in table


def test_replan_is_noop_and_pinned_needs_no_network(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    head = repo.rev("main")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", ref=head))
    assert lpam("apply", "--yes").returncode == 0
    git_daemon._stop()  # every connection attempt now fails
    again = lpam("plan", "--detailed-exitcode")
    assert again.returncode == 0, again.stderr
    assert "No changes" in again.stdout
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.events() == ["alpha:install:", "alpha:start:"]


def test_branch_moved_upstream_updates_only_what_changed(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", ref="main"))
    assert lpam("apply", "--yes").returncode == 0
    second = repo.commit("beta changes", {"beta/notes.txt": "x\n"})
    repo.push()
    plan = lpam("plan", "--detailed-exitcode")
    assert plan.returncode == 2 and "~ repository.apps: ref main moved" in plan.stdout
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.status()["repositories"][0]["commit"] == second
    assert lpam.events() == ["alpha:install:", "alpha:start:"]  # alpha's folder unchanged
    third = repo.commit("alpha changes", {"alpha/notes.txt": "y\n"})
    repo.push()
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.status()["app"]["commit"] == third
    assert lpam.events()[2:] == ["alpha:stop:", "alpha:uninstall:", "alpha:install:",
                                 "alpha:start:"]


def test_pin_older_hash_abbreviated_hash_and_tag(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    first = repo.rev("main")
    repo.tag("v1.0", message="annotated release")
    second = repo.commit("more", {"alpha/more.txt": "1\n"})
    repo.tag("light")
    repo.push()
    url = git_daemon.url("apps.git")
    for ref, expected in [(None, second), (first, first), (second[:8], second),
                          ("v1.0", first), ("light", second)]:
        lpam.desired(desired(url, "alpha", ref=ref))
        done = lpam("apply", "--yes")
        assert done.returncode == 0, (ref, done.stderr)
        status = lpam.status()
        assert status["repositories"][0]["commit"] == expected, ref
        assert status["app"]["commit"] == expected, ref
        assert (lpam.root / "var/lib/lpam/repositories/apps/alpha/install.sh").exists()


def test_switch_app_stops_and_uninstalls_before_installing(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, "beta"))
    assert lpam("plan", "--detailed-exitcode").returncode == 2
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert lpam.events() == ["alpha:install:", "alpha:start:", "alpha:stop:",
                             "alpha:uninstall:", "beta:install:", "beta:start:"]
    assert lpam.status()["app"]["name"] == "beta"
    generations = sorted(p.name for p in (lpam.root / "var/lib/lpam/generations").iterdir())
    assert generations == ["alpha", "beta"]  # alpha's is kept for `lpam rollback`
    # ... but only the installed app is where LPAM's scripts look for apps
    linked = sorted(p.name for p in (lpam.root / "etc/libpanda.d/apps").iterdir())
    assert linked == ["beta"]
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes", "--keep-generations", "1").returncode == 0
    generations = sorted(p.name for p in (lpam.root / "var/lib/lpam/generations").iterdir())
    assert generations == ["alpha"]  # only the installed one, as asked


def test_app_null_uninstalls_and_removed_repository_is_deleted(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, None))
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.events()[2:] == ["alpha:stop:", "alpha:uninstall:"]
    assert lpam.status()["app"] is None
    lpam.desired("version: 1\nrepositories: []\napp: null\n")
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.status()["repositories"] == []
    assert not (lpam.root / "var/lib/lpam/repositories/apps").exists()


def test_missing_ref_changes_nothing(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    before = lpam.status()
    for ref in ("no-such-branch", "0123456789abcdef0123456789abcdef01234567", "deadbee"):
        lpam.desired(desired(url, "beta", ref=ref))
        done = lpam("apply", "--yes")
        assert done.returncode == 1
        assert "not found" in done.stderr and "Traceback" not in done.stderr
        assert len(done.stderr.strip().splitlines()) <= 2
        assert lpam.status() == before
    assert lpam.events() == ["alpha:install:", "alpha:start:"]


def test_saved_plan_is_refused_after_the_state_changed(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon, tmp_path: Path
) -> None:
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    saved = tmp_path / "alpha.plan"
    assert lpam("plan", "--out", str(saved)).returncode == 0
    lpam.desired(desired(url, "beta"))
    assert lpam("apply", "--yes").returncode == 0
    refused = lpam("apply", str(saved))
    assert refused.returncode == 1 and "stale" in refused.stderr
    assert lpam.status()["app"]["name"] == "beta"
    fresh = tmp_path / "fresh.plan"
    lpam.desired(desired(url, "alpha"))
    assert lpam("plan", "--out", str(fresh), "--json").returncode == 0
    applied = lpam("apply", str(fresh))
    assert applied.returncode == 0, applied.stderr
    assert lpam.status()["app"]["name"] == "alpha"


def test_plan_json_has_format_version(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    import json

    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    plan = json.loads(lpam("plan", "--json").stdout)
    assert plan["format_version"] == 2
    assert [c["action"] for c in plan["changes"]] == ["create", "create"]
    assert [s["kind"] for s in plan["steps"]] == [
        "checkout", "stage", "install", "start", "verify"]


def test_local_edits_are_reported_and_never_thrown_away(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", ref="main"))
    assert lpam("apply", "--yes").returncode == 0
    edited = lpam.root / "var/lib/lpam/repositories/apps/alpha/install.sh"
    edited.write_text("# my field fix\n")
    repo.commit("upstream moves", {"beta/x.txt": "1\n"})
    repo.push()
    plan = lpam("plan")
    assert "local edits" in plan.stdout and "alpha/install.sh" in plan.stdout
    done = lpam("apply", "--yes")
    assert done.returncode == 1 and "alpha/install.sh" in done.stderr
    assert edited.read_text() == "# my field fix\n"
    assert lpam.status()["app"]["running"] is True


def test_url_change_reclones(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    file_url = f"file://{repo.bare}"
    lpam.desired(desired(file_url, "alpha"))
    plan = lpam("plan")
    assert "-/+ repository.apps: URL changed" in plan.stdout
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.status()["repositories"][0]["url"] == file_url
    assert lpam.events() == ["alpha:install:", "alpha:start:"]  # same folder: app untouched


def test_failing_script_stops_the_apply_with_a_clear_message(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    builder = make_repo("broken.git")
    builder.write("libpanda-apps.yaml", "apps:\n  - name: alpha\n")
    add_app(builder, "alpha", extra={"start": "exit 3"})
    builder.commit("broken start")
    builder.push()
    lpam.desired(desired(git_daemon.url("broken.git"), "alpha"))
    done = lpam("apply", "--yes")
    assert done.returncode == 1
    assert "start.sh failed with exit code 3" in done.stderr
    # whatever start.sh may have started is stopped: a failed first install leaves nothing
    assert "Removed the new app again. No app is installed now." in done.stderr
    assert "Traceback" not in done.stderr
    assert lpam.events() == ["alpha:install:", "alpha:start:", "alpha:stop:", "alpha:uninstall:"]
    assert lpam.status()["app"] is None
    assert "+ app.alpha: install alpha" in lpam("plan").stdout


def test_scripts_get_params_a_log_and_a_timeout(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    builder = make_repo("slow.git")
    builder.write("libpanda-apps.yaml", "apps:\n  - name: alpha\n")
    add_app(builder, "alpha", extra={
        "install": 'echo "dir=$PWD app_dir=$LPAM_APP_DIR rate=$RATE"',
        "start": "sleep 30",
    })
    builder.commit("slow start")
    builder.push()
    lpam.desired(desired(git_daemon.url("slow.git"), "alpha", RATE="10"))
    started = time.monotonic()
    done = lpam("apply", "--yes", "--script-timeout", "1")
    assert time.monotonic() - started < 25
    assert done.returncode == 1
    assert "start.sh did not finish within 1 s and was killed" in done.stderr
    logs = list((lpam.root / "var/log/lpam").glob("apply-*.log"))
    assert len(logs) == 1
    text = logs[0].read_text()
    generation = lpam.root / "var/lib/lpam/generations/alpha"
    gen_dir = next(p for p in generation.iterdir() if p.is_dir())
    # scripts run where LPAM put apps, a link to the generation: the field's scripts call
    # their helpers by that absolute path
    place = lpam.root / "etc/libpanda.d/apps/alpha"
    assert f"dir={place} app_dir={place} rate=10" in text
    assert gen_dir.is_dir() and not place.exists()  # the failed app was removed again


@pytest.mark.parametrize("failing", ["install", "start"])
def test_failed_cutover_rolls_back_to_the_previous_app(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon, failing: str
) -> None:
    apps_repo(make_repo("apps.git"), beta={failing: "exit 4"})
    url = git_daemon.url("apps.git")
    lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    lpam.desired(desired(url, "beta"))
    done = lpam("apply", "--yes")
    assert done.returncode == 1
    assert f"{failing}.sh failed with exit code 4" in done.stderr
    assert "Rolled back to alpha. Installed now: alpha (running)." in done.stderr
    # a failed start.sh may have started something: it is stopped before it is uninstalled
    beta_ran = ["beta:install:"] + (["beta:start:", "beta:stop:"] if failing == "start" else [])
    assert lpam.events() == [
        "alpha:install:", "alpha:start:", "alpha:stop:", "alpha:uninstall:",
        *beta_ran, "beta:uninstall:", "alpha:install:", "alpha:start:"]
    status = lpam.status()
    assert status["app"]["name"] == "alpha" and status["app"]["running"] is True
    assert lpam("plan", "--detailed-exitcode").returncode == 2  # beta is still wanted


def test_deleted_app_folder_is_restored_from_git(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    import shutil

    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    shutil.rmtree(lpam.root / "var/lib/lpam/generations/alpha")
    assert "folder is missing" in lpam("plan").stdout
    assert lpam("apply", "--yes").returncode == 0
    assert lpam.events()[2:] == ["alpha:stop:", "alpha:uninstall:", "alpha:install:",
                                 "alpha:start:"]
    assert lpam("plan", "--detailed-exitcode").returncode == 0


def test_one_failed_checkout_of_many_stops_the_apply_and_keeps_the_others(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon,
    make_repo: Callable[[str], RepoBuilder],
) -> None:
    """Several repositories are checked out at once: the one with local edits fails the
    apply by name, its edit is kept, the others are checked out and recorded, the app runs
    on untouched; once the edit is gone, the next apply finishes the job."""
    extras = [make_repo(f"lib{i}.git") for i in range(3)]
    for i, extra in enumerate(extras):
        extra.commit("first", {"lib.txt": f"{i}\n"})
        extra.push()
    urls = [git_daemon.url(f"lib{i}.git") for i in range(3)]
    text = desired(git_daemon.url("apps.git"), "alpha").replace(
        "app:", "".join(f"  - url: {u}\n    ref: main\n" for u in urls) + "app:")
    lpam.desired(text)
    assert lpam("apply", "--yes").returncode == 0
    edited = lpam.root / "var/lib/lpam/repositories/lib1/lib.txt"
    edited.write_text("my field fix\n")
    for extra in extras:
        extra.commit("second", {"lib.txt": "moved\n"})
        extra.push()
    done = lpam("apply", "--yes")
    assert done.returncode == 1
    assert "checkout:lib1" in done.stderr and "lib.txt" in done.stderr, done.stderr
    assert edited.read_text() == "my field fix\n"
    commits = {r["key"]: r["commit"] for r in lpam.status()["repositories"]}
    assert commits["lib0"] == extras[0].rev("main") and commits["lib2"] == extras[2].rev("main")
    assert commits["lib1"] != extras[1].rev("main")
    assert (lpam.root / "var/lib/lpam/repositories/lib2/lib.txt").read_text() == "moved\n"
    assert lpam.status()["app"]["running"] is True
    assert lpam.events() == ["alpha:install:", "alpha:start:"]
    edited.write_text("1\n")  # the edit undone: the checkout is clean again
    assert lpam("apply", "--yes").returncode == 0
    assert {r["key"]: r["commit"] for r in lpam.status()["repositories"]}["lib1"] == \
        extras[1].rev("main")
