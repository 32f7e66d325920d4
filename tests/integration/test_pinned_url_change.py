"""A pinned repository whose URL changed: the plan says what the apply needs of the network,
and the apply needs no more than that.

The field trial's plan promised no network for a pinned repository whose URL had changed,
then apply failed on `[Errno 111] Connection refused`. A commit names the same content
whichever remote brought it, so a pinned commit already in the store needs no fetch; one
that is not needs the network, and the plan says so. The real CLI, a real git daemon on
127.0.0.1, and a URL where nothing listens."""

from __future__ import annotations

from tests.gitserver import GitDaemon, RepoBuilder, closed_port
from tests.integration.apps import Lpam, desired


def test_a_pinned_commit_in_the_store_needs_no_network_when_its_url_changes(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    head = repo.rev("main")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", ref=head))
    assert lpam("apply", "--yes").returncode == 0
    with closed_port() as port:
        apply_offline(lpam, git_daemon, head, f"git://127.0.0.1:{port}/apps.git")


def apply_offline(lpam: Lpam, git_daemon: GitDaemon, head: str, refusing: str) -> None:
    lpam.desired(desired(refusing, "alpha", ref=head))
    plan = lpam("plan", "--detailed-exitcode")
    assert plan.returncode == 2, plan.stderr
    assert f"~ repository.apps: URL changed from {git_daemon.url('apps.git')} to {refusing}: " \
        f"commit {head[:12]} is already in the store, so no fetch and no network" in plan.stdout
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    assert lpam.status()["repositories"][0]["url"] == refusing
    assert lpam.events() == ["alpha:install:", "alpha:start:"]  # same folder: app untouched
    again = lpam("plan", "--detailed-exitcode")
    assert again.returncode == 0 and "No changes" in again.stdout, again.stdout


def test_a_pinned_commit_not_in_the_store_says_it_needs_the_network(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon
) -> None:
    head = repo.rev("main")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha", ref=head))
    assert lpam("apply", "--yes").returncode == 0
    later = repo.commit("later", {"alpha/notes.txt": "x\n"})
    repo.push()
    with closed_port() as port:
        refusing = f"git://127.0.0.1:{port}/apps.git"
        lpam.desired(desired(refusing, "alpha", ref=later))
        plan = lpam("plan")
        offline = lpam("plan", "--offline")
    assert plan.returncode == 1
    (line, *rest) = plan.stderr.strip().splitlines()
    assert line == (f"error: cannot fetch {refusing}: the server refused the connection "
                    f"(nothing listens at {refusing.split('/')[2]})"), plan.stderr
    assert "[Errno" not in plan.stderr and "?" not in plan.stderr
    assert rest and f"`lpam --root {lpam.root} plan --offline`" in rest[-1]  # as it runs
    assert "-/+ repository.apps: URL changed" in offline.stdout
    assert "a fetch over the network" in offline.stdout, offline.stdout
