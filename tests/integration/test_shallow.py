"""An app's repository is fetched one commit deep: the pinned tree, not years of history
(issue 32 item 3). Real `git daemon` on 127.0.0.1, real git for the figures lpam is held
to: a cold fetch of one pinned commit brings at most 1.5x the bytes of git's depth-1
fetch of it, and moving the pin one commit ahead at most 1.5x what git's fetch of that
commit into its depth-1 clone brings."""

from __future__ import annotations

import json
import random
import re
from collections.abc import Callable
from pathlib import Path

import pytest
from dulwich.objects import ObjectID
from dulwich.repo import Repo

from reconciler.adapters import bundle
from reconciler.adapters.git import GitStore
from reconciler.base.layout import Layout
from reconciler.engine.observe.targets import Fetch, resolve
from schemas.desired import DesiredState
from tests.gitserver import GitDaemon, RepoBuilder, run_git
from tests.integration.apps import Lpam
from tests.oldserver import OldProtocolRelay

KEY = "apps"
COMMITS = 30


@pytest.fixture
def history(make_repo: Callable[[str], RepoBuilder]) -> tuple[RepoBuilder, list[str]]:
    """A repository of COMMITS commits, each rewriting one of ten files with 3 kB of text
    no delta compresses: its history weighs many times its tree. Tag v1 (annotated)
    names the tenth commit."""
    repo = make_repo("apps.git")
    rand = random.Random(32)
    commits = []
    for n in range(COMMITS):
        text = "".join(rand.choice("abcdefghijklmnopqrstuvwxyz\n") for _ in range(3000))
        commits.append(repo.commit(f"c{n}", {f"data/f{n % 10}.txt": text}))
    repo.tag("v1", commits[9], message="the tenth")
    repo.push()
    return repo, commits


def store_of(tmp_path: Path, name: str = "root") -> tuple[GitStore, Layout]:
    layout = Layout(tmp_path / name)
    return GitStore(layout, timeout=20.0), layout


def shallow_list(layout: Layout) -> set[str]:
    listed = layout.repository_dir(KEY) / ".git" / "shallow"
    return set(listed.read_text().split()) if listed.exists() else set()


def git_pack_bytes(clone: Path, env: dict[str, str], url: str, commit: str) -> int:
    """The bytes of the pack git's `fetch --depth 1 URL COMMIT` brings into `clone`."""
    packs = clone / ".git" / "objects" / "pack"
    before = {p: p.stat().st_size for p in packs.glob("*.pack")} if packs.exists() else {}
    run_git("-c", "fetch.unpackLimit=1", "fetch", "--quiet", "--depth", "1", url, commit,
            cwd=clone, env=env)
    run_git("update-ref", "refs/remotes/origin/main", commit, cwd=clone, env=env)
    return sum(p.stat().st_size for p in packs.glob("*.pack") if p not in before)


def test_a_pinned_commit_comes_alone_within_one_and_a_half_times_gits_bytes(
    history: tuple[RepoBuilder, list[str]], git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    repo, commits = history
    url = git_daemon.url("apps.git")
    store, layout = store_of(tmp_path)
    pin = commits[20]  # not a tip: asked for by its hash
    first = store.fetch(KEY, url, want=pin)
    assert first.shallow and store.has_commit(KEY, pin)
    assert not store.has_commit(KEY, commits[19])  # no history
    assert shallow_list(layout) == {pin}
    assert store.read_file(KEY, pin, "data/f0.txt") is not None
    assert store.damage(KEY) is None

    clone = tmp_path / "git-clone"
    run_git("init", "--quiet", str(clone), cwd=tmp_path, env=repo.env)
    git_cold = git_pack_bytes(clone, repo.env, url, pin)
    assert 0 < first.bytes <= 1.5 * git_cold, (first.bytes, git_cold)

    moved = store.fetch(KEY, url, want=commits[21])  # the pin moved one commit ahead
    git_moved = git_pack_bytes(clone, repo.env, url, commits[21])
    assert store.has_commit(KEY, commits[21]) and moved.shallow
    assert 0 < moved.bytes <= 1.5 * git_moved, (moved.bytes, git_moved)
    assert moved.bytes < first.bytes / 5  # what the store had was not sent again
    assert store.fetch(KEY, url, want=commits[21]).bytes == 0  # held: nothing asked

    store.checkout(KEY, commits[21])  # a checkout of a shallow store is whole
    assert (layout.repository_dir(KEY) / "data/f1.txt").read_bytes() == \
        store.read_file(KEY, commits[21], "data/f1.txt")


def test_a_branch_or_tag_brings_its_commit_alone_and_resolves_offline_afterwards(
    history: tuple[RepoBuilder, list[str]], git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    _, commits = history
    url = git_daemon.url("apps.git")
    store, layout = store_of(tmp_path)
    for ref, commit in (("main", commits[-1]), ("v1", commits[9])):
        desired = DesiredState.model_validate(
            {"version": 2, "repositories": [{"url": url, "ref": ref}]})
        (online,) = resolve(desired, base_dir=layout.root, store=store,
                            fetch=Fetch.CHECKOUT).repositories
        assert online.commit == commit and online.fetched_alone and online.fetched
        (offline,) = resolve(desired, base_dir=layout.root, store=store,
                             fetch=Fetch.OFFLINE).repositories
        assert offline.commit == commit, ref  # what the last fetch saw
    assert shallow_list(layout) == {commits[-1], commits[9]}
    refs = store.local_refs(KEY)
    assert refs is not None and refs.resolve("main") == commits[-1]


def test_an_old_server_that_grants_only_tips_gives_the_history_instead(
    history: tuple[RepoBuilder, list[str]], git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    """A v0-only server refuses a commit that is no tip ("not our ref"): lpam fetches the
    tips with their whole history (a shallow store deepened to full) and goes on."""
    _, commits = history
    store, layout = store_of(tmp_path)
    with OldProtocolRelay(git_daemon.port) as old:
        url = old.url("apps.git")
        tip = store.fetch(KEY, url, want=commits[-1])  # a tip: granted, alone
        assert tip.shallow and shallow_list(layout) == {commits[-1]}
        older = store.fetch(KEY, url, want=commits[5])
    assert not older.shallow and older.bytes > tip.bytes
    assert all(store.has_commit(KEY, c) for c in commits)
    assert shallow_list(layout) == set()  # deepened to the whole history
    assert store.damage(KEY) is None


def test_a_deep_store_stays_usable_and_gets_only_what_it_lacks(
    history: tuple[RepoBuilder, list[str]], git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    repo, commits = history
    url = git_daemon.url("apps.git")
    store, layout = store_of(tmp_path)
    whole = store.fetch(KEY, url)  # as lpam fetched before issue 32: everything
    assert not whole.shallow and shallow_list(layout) == set()
    new = repo.commit("one more", {"data/f3.txt": "changed\n"})
    repo.push()
    brought = store.fetch(KEY, url, want=new)
    assert store.has_commit(KEY, new) and store.has_commit(KEY, commits[0])
    assert brought.bytes < whole.bytes / 20
    assert store.read_file(KEY, new, "data/f3.txt") == b"changed\n"


def test_a_commit_fetched_alone_travels_in_a_bundle_and_the_next_fetch_builds_on_it(
    history: tuple[RepoBuilder, list[str]], git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    """The laptop's store holds the pin one deep; the bundle carries it; the car adopts
    it, and a later fetch over the network negotiates from it without walking to the
    parents neither store has."""
    _, commits = history
    url = git_daemon.url("apps.git")
    laptop, laptop_layout = store_of(tmp_path, "laptop")
    laptop.fetch(KEY, url, want=commits[20])
    out = tmp_path / "apps.bundle"
    manifest = {"source": {"url": url, "branch": "main", "commit": commits[20]},
                "repositories": []}
    bundle.write(laptop_layout, out, branch="main", tip=commits[20], manifest=manifest,
                 pins=[(KEY, commits[20])])
    car, car_layout = store_of(tmp_path, "car")
    with bundle.opened(out) as (_, source):
        car.adopt(KEY, url, source, [commits[20]], {})
    assert car.has_commit(KEY, commits[20]) and shallow_list(car_layout) == {commits[20]}
    car.checkout(KEY, commits[20])
    moved = car.fetch(KEY, url, want=commits[21])
    assert car.has_commit(KEY, commits[21]) and moved.bytes < 20_000
    with Repo(str(car_layout.repository_dir(KEY))) as stored:
        assert ObjectID(commits[19].encode()) not in stored.object_store


def test_plan_and_apply_say_what_each_fetch_brought(
    history: tuple[RepoBuilder, list[str]], git_daemon: GitDaemon, tmp_path: Path,
) -> None:
    """On a metered link the user sees the bytes: a note on the terminal, a figure in
    `plan --json`; the fetch a plan made is not made again by the apply."""
    _, commits = history
    lpam = Lpam(tmp_path / "car")
    lpam.desired(f"version: 2\nrepositories:\n  - url: {git_daemon.url('apps.git')}\n"
                 f"    ref: {commits[20]}\napps: []\n")
    planned = lpam("plan", "--json")
    assert planned.returncode == 0, planned.stderr
    (fetched,) = json.loads(planned.stdout)["fetched"]
    assert fetched["key"] == "apps" and fetched["shallow"] and fetched["bytes"] > 10_000
    assert re.search(r"note: fetched apps from git://\S+: [\d.]+ kB \(the commit alone\)",
                     planned.stderr), planned.stderr
    applied = lpam("apply", "--yes")
    assert applied.returncode == 0, applied.stderr
    assert "note: fetched" not in applied.stderr  # the plan's fetch already holds it
    again = lpam("plan", "--json")
    assert json.loads(again.stdout)["fetched"] == [] and "fetched" not in again.stderr
