"""A damaged copy in the repository store (issue 18, item 10), with the real CLI, a real git
daemon and the damage a power cut or a failing SD card leaves in a pack.

Before: `lpam status`, `plan` and `apply` ended in "internal error" (dulwich's
ChecksumMismatch, zlib.error or AssertionError), or — with a pack's index gone — status
said the commit was missing and nothing else. Now status keeps the repository's row with
the damage and answers for the rest, a plan refuses the copy naming the repository and what
the next apply does, and apply fetches it anew and goes on; without network nothing moves.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path

import pytest

from reconciler.base.layout import Layout
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo, desired
from tests.integration.conftest import fleet_state

DAMAGES = ["truncated", "flipped", "index-deleted", "emptied"]


def damage(lpam: Lpam, key: str, how: str) -> None:
    """Damage the newest pack of `key`'s copy in the store, as a power cut or an SD card
    that fails does (packs are read-only files: made writable first)."""
    folder = Layout(lpam.root).repository_dir(key) / ".git" / "objects" / "pack"
    packs = sorted(folder.glob("*.pack"), key=lambda p: p.stat().st_mtime_ns)
    pack = packs[-1]
    pack.chmod(0o644)
    data = bytearray(pack.read_bytes())
    if how == "truncated":
        pack.write_bytes(data[: len(data) // 2])
    elif how == "flipped":
        data[len(data) // 2] ^= 0xFF
        pack.write_bytes(bytes(data))
    elif how == "index-deleted":
        pack.with_suffix(".idx").unlink()
    else:
        pack.write_bytes(b"")


def snapshot(path: Path) -> dict[str, str]:
    """Every file under `path` with a hash of its content: what a plan must not change."""
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.fixture
def two(lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon) -> Lpam:
    """alpha running from apps.git, beside a second repository (tools.git, app gamma)."""
    apps_repo(make_repo("apps.git"))
    tools = make_repo("tools.git")
    tools.write("libpanda-apps.yaml", "apps:\n  - name: gamma\n")
    tools.write("gamma/description.txt", "the gamma app\n")
    tools.commit("gamma")
    tools.push()
    lpam.desired(two_repositories(git_daemon, "alpha"))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    return lpam


def two_repositories(git_daemon: GitDaemon, app: str) -> str:
    return (f"version: 1\nrepositories:\n  - url: {git_daemon.url('apps.git')}\n"
            f"  - url: {git_daemon.url('tools.git')}\napp: {app}\n")


@pytest.mark.parametrize("how", [d for d in DAMAGES if d != "flipped"])
def test_status_names_the_damaged_repository_and_answers_for_the_rest(
    two: Lpam, how: str,
) -> None:
    """Status reads only what it shows (a few objects), so it sees the damage that touches
    them — a pack cut short or emptied fails its first read, a lost index hides the commit
    — and not a flipped byte in an object it does not read: what it shows is whole (each
    object inflates under zlib's checksum), and plan and apply check every byte."""
    damage(two, "apps", how)
    table = two("status")
    assert table.returncode == 0 and table.stderr == "", table.stderr
    rows = table.stdout.splitlines()
    assert any(r.startswith("apps ") and f"(damaged in the store: the next `lpam --root "
               f"{two.root} apply` fetches it anew)" in r for r in rows), table.stdout
    assert any(r.startswith("tools ") and "gamma" in r and "the gamma app" in r for r in rows)
    assert any(r.startswith("apps ") and " alpha " in r and " running" in r for r in rows)
    [note] = [r for r in rows if r.startswith("Repository apps: its copy in the store is "
                                              "damaged: ")]
    assert ("does not match its checksum" in note or "is truncated" in note
            or "which is not in the store" in note), note
    shown = two.status()
    assert [(r["repository"], r["app"]) for r in shown["apps"]] == [
        ("apps", "-"), ("tools", "gamma"), ("apps", "alpha")]
    assert shown["apps"][0]["damage"] and shown["app"]["name"] == "alpha"


@pytest.mark.parametrize("how", DAMAGES)
def test_plan_refuses_a_damaged_copy_and_says_apply_fetches_it_anew(
    two: Lpam, git_daemon: GitDaemon, how: str,
) -> None:
    damage(two, "apps", how)
    store = two.root / "var/lib/lpam/repositories"
    before = snapshot(store)
    for offline in ([], ["--offline"]):
        done = two("plan", *offline)
        assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
        error, hint = done.stderr.splitlines()
        assert error.startswith("error: repository apps: its copy in the store is damaged: ")
        assert error.endswith(f"({store / 'apps'})")
        assert hint == (f"  hint: the store is a cache: the next `lpam --root {two.root} "
                        "apply` moves the "
                        f"damaged copy aside and fetches it anew from "
                        f"{git_daemon.url('apps.git')}; nothing was changed")
    assert snapshot(store) == before


@pytest.mark.parametrize("how", DAMAGES)
def test_apply_fetches_the_damaged_copy_anew_and_leaves_the_running_app(
    two: Lpam, how: str,
) -> None:
    damage(two, "apps", how)
    done = two("apply", "--yes")
    assert done.returncode == 0, done.stderr
    aside = two.root / "var/lib/lpam/repositories/.apps~damaged"
    assert ("note: repository apps: its copy in the store was damaged (" in done.stderr
            and f"the damaged copy kept at {aside}" in done.stderr), done.stderr
    assert two.events() == ["alpha:install:", "alpha:start:"]  # alpha untouched
    assert aside.is_dir()
    shown = two.status()
    assert all(r["damage"] is None for r in shown["apps"])
    assert shown["app"]["name"] == "alpha" and shown["app"]["running"]
    again = two("plan", "--detailed-exitcode")
    assert again.returncode == 0 and "No changes" in again.stdout, again.stdout


def test_apply_goes_on_with_the_change_it_was_asked_for(
    two: Lpam, git_daemon: GitDaemon,
) -> None:
    damage(two, "apps", "truncated")
    two.desired(two_repositories(git_daemon, "beta"))
    done = two("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert "fetched anew" in done.stderr
    assert two.events()[2:] == ["alpha:stop:", "alpha:uninstall:", "beta:install:",
                                "beta:start:"]


def test_without_network_apply_changes_nothing_and_says_so(
    two: Lpam, git_daemon: GitDaemon,
) -> None:
    damage(two, "apps", "truncated")
    store = two.root / "var/lib/lpam/repositories"
    before = snapshot(store)
    git_daemon.stop()
    done = two("apply", "--yes", "--network-timeout", "5")
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    error, hint = done.stderr.splitlines()
    assert error.startswith("error: repository apps: its copy in the store is damaged: ")
    assert f"; fetching it anew failed: cannot fetch {git_daemon.url('apps.git')}" in error
    assert hint == ("  hint: nothing was changed and the running app is untouched; the next "
                    f"`lpam --root {two.root} apply` with network fetches it anew")
    assert snapshot(store) == before
    assert two.events() == ["alpha:install:", "alpha:start:"]
    assert two.status()["app"]["running"]


def test_a_saved_plan_made_before_the_damage_fetches_it_anew(
    lpam: Lpam, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
) -> None:
    """The checkout step of a saved plan meets the damage itself (apply PLAN resolves
    nothing): it fetches the copy anew and goes on."""
    repo = make_repo("apps.git")
    apps_repo(repo)
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    repo.commit("alpha two", {"alpha/description.txt": "alpha, second\n"})
    repo.push()
    saved = lpam.root / "plan.json"
    assert lpam("plan", "-o", str(saved)).returncode == 0
    damage(lpam, "apps", "truncated")
    done = lpam("apply", str(saved))
    assert done.returncode == 0, done.stderr
    assert lpam.status()["repositories"][0]["commit"] == repo.rev("main")
    logs = "".join(p.read_text() for p in (lpam.root / "var/log/lpam").glob("apply-*.log"))
    assert "its copy in the store was damaged" in logs and "fetched anew" in logs


def test_the_agent_fetches_a_damaged_source_or_app_repository_anew(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon,
) -> None:
    assert car("sync").returncode == 0
    # the source is only read; the app repository's checkout is put back (one step)
    for key, result in (("@source", "nothing to do"), ("apps", "applied")):
        damage(car, key, "truncated")
        done = car("sync")
        assert done.returncode == 0, done.stderr
        assert f"repository {key}: its copy in the store was damaged" in done.stderr
        assert car.events() == ["alpha:install:one", "alpha:start:one"]
        status = json.loads((car.root / "var/lib/lpam/status.json").read_text())
        assert status["last_attempt"]["result"] == result


def test_the_agent_without_network_is_offline_not_failed(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon,
) -> None:
    """A damaged copy is not the revision's fault: it is tried again once there is
    network, not marked failed for good."""
    assert car("sync").returncode == 0
    damage(car, "@source", "truncated")
    git_daemon.stop()
    done = car("sync", "--network-timeout", "5")
    assert done.returncode == 0, done.stderr
    status = json.loads((car.root / "var/lib/lpam/status.json").read_text())
    assert status["last_attempt"]["result"] == "offline"
    assert "its copy in the store is damaged" in status["last_attempt"]["reason"]
    assert car.events() == ["alpha:install:one", "alpha:start:one"]


def test_a_new_revision_meeting_a_damaged_copy_offline_is_tried_again_later(
    car: Lpam, fleet: RepoBuilder, git_daemon: GitDaemon,
) -> None:
    """What WiFi brought at the end of a trip (`sync --fetch-only`) is applied offline at
    the next start; a damaged app repository then stops it, but the revision is not
    marked failed: the next pass with network fetches the copy anew and applies it."""
    assert car("sync").returncode == 0
    fleet.commit("faster", {"desired-state.yaml": fleet_state("alpha", MODE="two")})
    fleet.push()
    assert car("sync", "--fetch-only").returncode == 0
    damage(car, "apps", "truncated")
    git_daemon.stop()
    done = car("sync", "--network-timeout", "5")
    assert done.returncode == 0, done.stderr
    status = json.loads((car.root / "var/lib/lpam/status.json").read_text())
    assert (status["last_attempt"]["result"], status["last_attempt"]["revision"]) == (
        "offline", fleet.rev("HEAD"))
    assert "repository apps: its copy in the store is damaged" in \
        status["last_attempt"]["reason"]
    assert car.events() == ["alpha:install:one", "alpha:start:one"]
