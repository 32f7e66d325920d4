"""Plans that tell the truth: a plan lists exactly the steps apply will run, moves nothing,
and says so when it cannot know (offline, or beside a running apply).

Each test is a lie a plan used to tell (issue 5): a reinstall for a branch that moved
only another app's folder, "switch from X to X" for an app whose repository was not
fetched, "to add" for an ambiguous app that apply then refused, a saved plan with
unknown values accepted, "the last apply was interrupted" beside a running one.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from reconciler.core.planning.plan import fingerprint
from schemas.plan import Plan
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, add_app, apps_repo, desired
from tests.integration.test_bus_safety import HANG_UNTIL_RELEASED
from tests.integration.test_crash import descendants, wait_for, wait_gone


def checkout(lpam: Lpam, key: str = "apps") -> Path:
    return lpam.root / "var/lib/lpam/repositories" / key


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file of a checkout, `.git/HEAD` and `.git/index` included."""
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*"))
            if p.is_file() and (".git" not in p.parts or p.name in ("HEAD", "index"))
            and p.parent.name != "logs"}


def two_repos(lpam: Lpam, git_daemon: GitDaemon, app: str) -> str:
    return "\n".join([
        "version: 1",
        "repositories:",
        f"  - url: {git_daemon.url('apps.git')}",
        f"  - url: {git_daemon.url('more.git')}",
        f"app: {{name: {app}}}",
    ]) + "\n"


def test_a_plan_after_a_branch_moved_is_exact_and_moves_no_checkout(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    apps_repo(repo)
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", ref="main"))
    assert lpam("apply", "--yes").returncode == 0
    before = snapshot(checkout(lpam))
    repo.commit("only beta changes", {"beta/notes.txt": "x\n"})
    repo.push()
    plan = lpam("plan", "--json")
    assert plan.returncode == 0, plan.stderr
    steps = [s["kind"] for s in json.loads(plan.stdout)["steps"]]
    assert steps == ["checkout"]  # alpha's folder did not change: no reinstall
    assert snapshot(checkout(lpam)) == before  # HEAD, index and files untouched
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert lpam.events() == ["alpha:install:", "alpha:start:"]


def test_a_plan_names_the_repository_that_offers_the_app(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    more = make_repo("more.git")
    more.write("libpanda-apps.yaml", "apps:\n  - name: gamma\n")
    add_app(more, "gamma")
    more.commit("gamma")
    more.push()
    lpam.desired(two_repos(lpam, git_daemon, "gamma"))
    plan = lpam("plan")
    assert plan.returncode == 0, plan.stderr
    assert "+ app.gamma: install gamma from more" in plan.stdout
    assert "known after fetch" not in plan.stdout
    lpam.desired(two_repos(lpam, git_daemon, "delta"))
    missing = lpam("plan")
    assert missing.returncode == 1
    assert "app delta is not in the catalog" in missing.stderr and "gamma (more)" in missing.stderr


def test_an_ambiguous_app_is_refused_by_the_plan_not_only_by_apply(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    apps_repo(make_repo("more.git"))
    lpam.desired(two_repos(lpam, git_daemon, "alpha"))
    plan = lpam("plan")
    assert plan.returncode == 1
    assert "offered by apps and more" in plan.stderr and "repository:" in plan.stderr


def test_an_offline_plan_uses_no_network_says_so_and_cannot_be_applied(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon, tmp_path: Path
) -> None:
    repo = make_repo("apps.git")
    apps_repo(repo)
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", ref="main"))
    assert lpam("apply", "--yes").returncode == 0
    repo.commit("alpha changes", {"alpha/notes.txt": "y\n"})
    repo.push()
    assert lpam("plan").returncode == 0  # fetches the new commit's objects
    git_daemon._stop()
    offline = lpam("plan", "--offline", "--detailed-exitcode")
    assert offline.returncode == 2, offline.stderr
    assert "ref main (offline: as of the last fetch) moved" in offline.stdout
    assert "new version (folder" in offline.stdout  # the objects are local: known exactly
    assert "Offline plan" in offline.stdout
    refused = lpam("plan", "--offline", "--out", str(tmp_path / "p.json"))
    assert refused.returncode == 1 and "cannot be saved" in refused.stderr
    assert not (tmp_path / "p.json").exists()
    online = lpam("plan", "--network-timeout", "5")
    assert online.returncode == 1 and "Traceback" not in online.stderr
    saved = tmp_path / "offline.json"
    saved.write_text(lpam("plan", "--offline", "--json").stdout)
    applied = lpam("apply", str(saved))
    assert applied.returncode == 1 and "offline" in applied.stderr
    assert lpam.events() == ["alpha:install:", "alpha:start:"]


def test_a_saved_plan_with_values_still_unknown_is_refused(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon, tmp_path: Path
) -> None:
    apps_repo(make_repo("apps.git"))
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", ref="main"))
    git_daemon._stop()  # nothing fetched yet: the offline plan knows no commit
    shown = lpam("plan", "--offline", "--json")
    assert shown.returncode == 0, shown.stderr
    plan = Plan.model_validate_json(shown.stdout).model_copy(update={"offline": False})
    sealed = plan.model_copy(update={"fingerprint": fingerprint(plan)})  # a careful forger
    saved = tmp_path / "forged.json"
    saved.write_text(sealed.model_dump_json())
    applied = lpam("apply", str(saved))
    assert applied.returncode == 1
    assert "still unknown" in applied.stderr and "checkout:apps.commit" in applied.stderr


def test_a_plan_beside_a_running_apply_says_so_and_a_saved_plan_waits_for_the_lock(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon, tmp_path: Path
) -> None:
    apps_repo(make_repo("apps.git"), alpha={"start": HANG_UNTIL_RELEASED})
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    apply = lpam.spawn("apply", "--yes")
    pids: list[int] = []
    try:
        wait_for(lpam.root / "start-began")
        pids = descendants(apply.pid)
        beside = lpam("plan", "--lock-timeout", "0.3")
        assert beside.returncode == 0, beside.stderr
        assert "an apply in progress" in beside.stderr and "start.sh" in beside.stderr
        assert "interrupted" not in beside.stderr
        saved = lpam("plan", "--out", str(tmp_path / "p.json"), "--lock-timeout", "0.3")
        assert saved.returncode == 1 and "another lpam apply holds" in saved.stderr
        assert not (tmp_path / "p.json").exists()
    finally:
        (lpam.root / "release").touch()
        try:
            apply.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            apply.kill()
        for pid in pids:
            wait_gone(pid, seconds=30)
    assert apply.returncode == 0
    assert lpam("plan", "--detailed-exitcode").returncode == 0


@pytest.fixture
def logged(tmp_path_factory: pytest.TempPathFactory, hermetic_env: Path) -> Iterator[GitDaemon]:
    """A git daemon that logs every connection: what lpam asked of the network."""
    log = tmp_path_factory.mktemp("daemon-log") / "daemon.log"
    with GitDaemon(tmp_path_factory.mktemp("served"), home=hermetic_env, log=log) as daemon:
        yield daemon


def connections(daemon: GitDaemon) -> int:
    assert daemon.log is not None
    return daemon.log.read_text().count("Request upload-pack")


def test_the_network_is_asked_only_what_is_not_local(
    lpam: Lpam, logged: GitDaemon, tmp_path_factory: pytest.TempPathFactory, hermetic_env: Path
) -> None:
    repo = RepoBuilder(logged.base, "apps.git", work_root=tmp_path_factory.mktemp("work"),
                       home=hermetic_env)
    apps_repo(repo)
    lpam.desired(desired(logged.url("apps.git"), "alpha", ref="main"))
    assert lpam("apply", "--yes").returncode == 0
    count = connections(logged)
    assert lpam("plan").returncode == 0  # main has not moved: where is it? (one ls-remote)
    assert connections(logged) == count + 1
    assert lpam("apply", "--yes").returncode == 0  # nothing to fetch either
    assert connections(logged) == count + 2
    repo.commit("alpha changes", {"alpha/notes.txt": "y\n"})
    repo.push()
    assert lpam("plan").returncode == 0  # main moved: ls-remote, then fetch its objects
    assert connections(logged) == count + 4
    done = lpam("apply", "--yes")  # the plan fetched them: apply only asks where main is
    assert done.returncode == 0, done.stderr
    assert connections(logged) == count + 5
    assert lpam.events()[-2:] == ["alpha:install:", "alpha:start:"]
