"""The repository store against real servers: `git daemon` on loopback, file:// and paths.

The git CLI is the oracle: what lpam checks out must look right to `git status` and
`git rev-parse`, because that is what an operator will run on the vehicle.
"""

from __future__ import annotations

import hashlib
import os
import re
import socket
import stat
import subprocess
import tracemalloc
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from dulwich.objects import Blob
from dulwich.repo import Repo

from reconciler.adapters.git import GitStore
from reconciler.adapters.objectsize import object_size
from reconciler.base.errors import GitError, LocalEditsError, RefNotFoundError
from reconciler.base.layout import Layout
from tests.gitserver import FIXED_ENV, GitDaemon, RepoBuilder, free_port

KEY = "lab/apps"


@dataclass
class Served:
    repo: RepoBuilder
    url: str
    c1: str  # main: c1 ── c2 ── c4      tags: v1 (lightweight) at c1, v2 (annotated) at c2
    c2: str  # dev:         └── c3
    c3: str
    c4: str


@pytest.fixture
def served(make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon) -> Served:
    repo = make_repo("lab/apps.git")
    repo.write("app/run.sh", "#!/bin/sh\necho one\n", executable=True)
    repo.symlink("app/start", "run.sh")
    c1 = repo.commit("first", {"README": "one\n", "app/params.yaml": "speed: 1\n"})
    repo.tag("v1")
    c2 = repo.commit("second", {"app/params.yaml": "speed: 2\n", "app/lib/helper.py": "x = 2\n"})
    repo.tag("v2", message="release two")
    repo.branch("dev")
    repo.switch("dev")
    c3 = repo.commit("on dev", {"dev.txt": "dev\n"})
    repo.switch("main")
    c4 = repo.commit("third", {"README": "three\n"})
    repo.push()
    return Served(repo, git_daemon.url("lab/apps.git"), c1, c2, c3, c4)


@pytest.fixture
def layout(tmp_path: Path) -> Layout:
    return Layout(root=tmp_path / "root")


@pytest.fixture
def store(layout: Layout) -> GitStore:
    return GitStore(layout, timeout=10.0)


def git_out(checkout: Path, *args: str) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_")} | FIXED_ENV
    return subprocess.run(
        ["git", *args], cwd=checkout, env=env, capture_output=True, text=True, check=True
    ).stdout.strip()


def transports(served: Served) -> dict[str, str]:
    return {"git": served.url, "file": served.repo.bare.as_uri(), "path": str(served.repo.bare)}


# -- ls_remote ----------------------------------------------------------------------------


@pytest.mark.parametrize("transport", ["git", "file", "path"])
def test_ls_remote_lists_tips_with_annotated_tags_peeled(
    served: Served, store: GitStore, transport: str
) -> None:
    url = transports(served)[transport]
    remote = store.ls_remote(url)

    assert remote.url == url
    assert remote.refs == {
        "refs/heads/main": served.c4,
        "refs/heads/dev": served.c3,
        "refs/tags/v1": served.c1,
        "refs/tags/v2": served.c2,
    }
    assert remote.default_branch == "main"
    assert remote.resolve(None) == served.c4
    assert remote.resolve("dev") == served.c3
    assert remote.resolve("refs/heads/dev") == served.c3
    assert remote.resolve("v2") == served.c2
    assert remote.resolve("refs/tags/v1") == served.c1
    assert remote.resolve(served.c3) == served.c3
    assert remote.resolve("nope") is None
    assert remote.resolve(served.c3[:12]) is None  # abbreviations need the objects: resolve_local


def test_default_branch_follows_the_remote_head(served: Served, store: GitStore) -> None:
    subprocess.run(
        ["git", "symbolic-ref", "HEAD", "refs/heads/dev"], cwd=served.repo.bare, check=True
    )
    remote = store.ls_remote(served.url)
    assert remote.default_branch == "dev"
    assert remote.resolve(None) == served.c3


def test_nothing_is_written_by_ls_remote(served: Served, store: GitStore, layout: Layout) -> None:
    store.ls_remote(served.url)
    assert not layout.root.exists()


# -- fetch and checkout -------------------------------------------------------------------


def test_fetch_then_checkout_branch_tip(served: Served, store: GitStore, layout: Layout) -> None:
    assert store.head(KEY) is None
    assert not store.has_commit(KEY, served.c4)

    store.fetch(KEY, served.url)

    checkout = layout.repository_dir(KEY)
    assert store.origin_url(KEY) == served.url
    assert store.head(KEY) is None  # fetched, not yet checked out
    assert all(store.has_commit(KEY, c) for c in (served.c1, served.c2, served.c3, served.c4))
    assert git_out(
        checkout, "rev-parse", "origin/main", "origin/dev", "v1^{commit}", "v2^{commit}"
    ).split() == [served.c4, served.c3, served.c1, served.c2]

    store.checkout(KEY, served.c4)

    assert store.head(KEY) == served.c4
    assert git_out(checkout, "rev-parse", "HEAD") == served.c4
    assert git_out(checkout, "branch", "--show-current") == ""  # detached
    assert git_out(checkout, "status", "--porcelain") == ""
    assert (checkout / "README").read_text() == "three\n"
    assert (checkout / "app/run.sh").stat().st_mode & stat.S_IXUSR
    assert os.readlink(checkout / "app/start") == "run.sh"
    assert store.local_edits(KEY) == []


def test_checkout_an_older_full_hash_removes_later_files(
    served: Served, store: GitStore, layout: Layout
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    store.checkout(KEY, served.c1)

    checkout = layout.repository_dir(KEY)
    assert store.head(KEY) == served.c1
    assert (checkout / "app/params.yaml").read_text() == "speed: 1\n"
    assert not (checkout / "app/lib").exists()
    assert git_out(checkout, "status", "--porcelain") == ""


def test_abbreviated_hash_resolves_after_fetch(served: Served, store: GitStore) -> None:
    assert store.resolve_local(KEY, served.c3[:7]) is None  # nothing fetched yet
    store.fetch(KEY, served.url)

    full = store.resolve_local(KEY, served.c3[:7].upper())
    assert full == served.c3
    store.checkout(KEY, full)
    assert store.head(KEY) == served.c3
    assert store.resolve_local(KEY, "main") is None
    assert store.resolve_local(KEY, "0000000") is None


def test_checkout_of_an_absent_commit_is_refused(served: Served, store: GitStore) -> None:
    with pytest.raises(RefNotFoundError):
        store.checkout(KEY, served.c1)
    store.fetch(KEY, served.url)
    with pytest.raises(RefNotFoundError, match="0123456789"):
        store.checkout(KEY, "0123456789" * 4)


def test_a_moved_branch_is_seen_by_the_next_fetch(
    served: Served, store: GitStore, layout: Layout
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    c5 = served.repo.commit("fourth", {"README": "five\n"})
    served.repo.push()

    assert store.ls_remote(served.url).resolve("main") == c5
    assert not store.has_commit(KEY, c5)
    store.fetch(KEY, served.url)

    assert store.has_commit(KEY, c5)
    assert git_out(layout.repository_dir(KEY), "rev-parse", "origin/main") == c5
    assert store.head(KEY) == served.c4  # fetching never moves the checkout


def test_a_deleted_branch_disappears_from_origin(
    served: Served, store: GitStore, layout: Layout
) -> None:
    store.fetch(KEY, served.url)
    subprocess.run(
        ["git", "branch", "-D", "dev"], cwd=served.repo.bare, check=True, capture_output=True
    )
    store.fetch(KEY, served.url)
    assert git_out(layout.repository_dir(KEY), "branch", "-r").split() == ["origin/main"]


# -- failures -----------------------------------------------------------------------------


def assert_store_untouched(layout: Layout) -> None:
    repos = layout.repositories
    assert not repos.exists() or list(repos.iterdir()) == []


def test_unreachable_server_is_a_git_error(store: GitStore, layout: Layout) -> None:
    url = f"git://127.0.0.1:{free_port()}/lab/apps.git"  # nothing listens there
    with pytest.raises(GitError, match=re.escape(url)) as caught:
        store.fetch(KEY, url)
    assert url in caught.value.message
    assert caught.value.hint and "network" in caught.value.hint
    assert "\n" not in caught.value.message
    assert not layout.repository_dir(KEY).exists()
    assert_store_untouched(layout)
    with pytest.raises(GitError):
        store.ls_remote(url)


def test_refetch_while_offline_changes_nothing(
    served: Served, store: GitStore, git_daemon: GitDaemon, layout: Layout
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    git_daemon.__exit__(None, None, None)  # the WiFi is gone

    with pytest.raises(GitError, match=re.escape(served.url)):
        store.fetch(KEY, served.url)

    assert store.head(KEY) == served.c4
    assert store.origin_url(KEY) == served.url
    assert git_out(layout.repository_dir(KEY), "rev-parse", "origin/main") == served.c4
    assert [p.name for p in layout.repositories.iterdir()] == [layout.repository_dir(KEY).name]


def test_a_foreign_directory_in_the_store_is_left_alone(
    served: Served, store: GitStore, layout: Layout
) -> None:
    foreign = layout.repository_dir(KEY)
    foreign.mkdir(parents=True)
    (foreign / "results.csv").write_text("keep me\n")

    with pytest.raises(GitError, match="not a git checkout"):
        store.fetch(KEY, served.url)
    with pytest.raises(GitError, match="not a git checkout"):
        store.remove(KEY)
    assert (foreign / "results.csv").read_text() == "keep me\n"


def test_missing_repository_on_the_server(
    git_daemon: GitDaemon, store: GitStore, layout: Layout
) -> None:
    url = git_daemon.url("lab/missing.git")
    with pytest.raises(GitError, match="no such repository"):
        store.ls_remote(url)
    with pytest.raises(GitError, match=re.escape(url)):
        store.fetch(KEY, url)
    assert_store_untouched(layout)


def test_missing_local_repository(tmp_path: Path, store: GitStore, layout: Layout) -> None:
    with pytest.raises(GitError, match="nowhere"):
        store.fetch(KEY, str(tmp_path / "nowhere"))
    assert_store_untouched(layout)


@pytest.mark.parametrize("url", ["ftp://host/repo", "git://", "relative/path", "https:///x"])
def test_unusable_urls_are_refused(store: GitStore, url: str) -> None:
    with pytest.raises(GitError):
        store.ls_remote(url)


def test_a_silent_server_times_out(layout: Layout) -> None:
    with socket.socket() as listener:  # accepts connections (backlog) but never answers
        listener.bind(("127.0.0.1", 0))
        listener.listen(1)
        url = f"git://127.0.0.1:{listener.getsockname()[1]}/lab/apps.git"
        with pytest.raises(GitError, match=re.escape("no answer within 0.5 s")):
            GitStore(layout, timeout=0.5).fetch(KEY, url)
    assert_store_untouched(layout)


# -- URL changes --------------------------------------------------------------------------


def test_url_change_reclones_from_the_new_url(
    served: Served, store: GitStore, make_repo: Callable[[str], RepoBuilder]
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    fork = make_repo("fork/apps.git")
    forked = fork.commit("fork", {"README": "fork\n"})
    fork.push()
    new_url = fork.bare.as_uri()

    store.fetch(KEY, new_url)

    assert store.origin_url(KEY) == new_url
    assert store.has_commit(KEY, forked)
    assert not store.has_commit(KEY, served.c4)
    store.checkout(KEY, forked)
    assert store.head(KEY) == forked


def test_url_change_is_refused_over_local_edits(
    served: Served, store: GitStore, layout: Layout, make_repo: Callable[[str], RepoBuilder]
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    (layout.repository_dir(KEY) / "notes.txt").write_text("mine\n")
    fork = make_repo("fork/apps.git")
    fork.commit("fork")
    fork.push()

    with pytest.raises(LocalEditsError, match=re.escape("notes.txt")):
        store.fetch(KEY, fork.bare.as_uri())
    assert store.origin_url(KEY) == served.url
    assert (layout.repository_dir(KEY) / "notes.txt").read_text() == "mine\n"


# -- local edits --------------------------------------------------------------------------


def test_local_edits_are_reported_and_refused(
    served: Served, store: GitStore, layout: Layout
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    checkout = layout.repository_dir(KEY)
    (checkout / "README").write_text("edited on the car\n")
    (checkout / "app/params.yaml").unlink()
    (checkout / "data").mkdir()
    (checkout / "data/run1.csv").write_text("1,2\n")

    assert store.local_edits(KEY) == ["README", "app/params.yaml", "data/run1.csv"]
    with pytest.raises(LocalEditsError) as caught:
        store.checkout(KEY, served.c1)
    assert "README" in caught.value.message and "data/run1.csv" in caught.value.message
    assert caught.value.hint and "delete" in caught.value.hint
    assert (checkout / "README").read_text() == "edited on the car\n"
    assert (checkout / "data/run1.csv").exists()
    assert store.head(KEY) == served.c4
    with pytest.raises(LocalEditsError):
        store.remove(KEY)
    assert checkout.exists()


def test_interrupted_checkout_is_finished_not_refused(
    served: Served, store: GitStore, layout: Layout
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    checkout = layout.repository_dir(KEY)
    # what a power cut half-way through checking out c1 leaves behind
    (checkout / ".git/lpam-checkout").write_text(served.c1 + "\n")
    (checkout / "app/params.yaml").write_text("speed: 1\n")
    (checkout / "app/lib/helper.py").unlink()

    assert store.local_edits(KEY) == []
    store.checkout(KEY, served.c3)  # the next apply may want another commit

    assert store.head(KEY) == served.c3
    assert git_out(checkout, "status", "--porcelain") == ""
    assert (checkout / "app/params.yaml").read_text() == "speed: 2\n"
    assert (checkout / "app/lib/helper.py").read_text() == "x = 2\n"
    assert not (checkout / ".git/lpam-checkout").exists()


def test_lock_files_a_killed_write_left_do_not_block_the_store(
    served: Served, store: GitStore, layout: Layout
) -> None:
    """dulwich writes a ref, HEAD, the index, the config as NAME.lock renamed over NAME; an
    lpam killed in between leaves NAME.lock, and the next fetch or checkout of that name was
    refused (FileLocked: an internal error, found by the long random-fault run). Every
    write to the store is made under the apply lock, so the next writer removes them."""
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c1)
    checkout = layout.repository_dir(KEY)
    left = [".git/refs/remotes/origin/main.lock", ".git/refs/tags/v1.lock", ".git/HEAD.lock",
            ".git/index.lock", ".git/config.lock"]
    for name in left:  # half-written, as a kill leaves them
        (checkout / name).write_bytes(b"3f0")
    c5 = served.repo.commit("fifth", {"README": "five\n"})
    served.repo.push()

    store.fetch(KEY, served.url)
    store.checkout(KEY, c5)

    assert git_out(checkout, "rev-parse", "origin/main", "HEAD").split() == [c5, c5]
    assert git_out(checkout, "status", "--porcelain") == ""
    assert (checkout / "README").read_text() == "five\n"
    assert sorted(p.name for p in (checkout / ".git").rglob("*.lock")) == []


def test_remove_deletes_the_checkout(served: Served, store: GitStore, layout: Layout) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    store.remove(KEY)
    assert store.head(KEY) is None
    assert_store_untouched(layout)
    store.remove(KEY)  # removing what is absent is a no-op


# -- reading and exporting ----------------------------------------------------------------


def test_read_file_and_folder_tree(served: Served, store: GitStore) -> None:
    store.fetch(KEY, served.url)
    assert store.read_file(KEY, served.c1, "README") == b"one\n"
    assert store.read_file(KEY, served.c4, "README") == b"three\n"
    assert store.read_file(KEY, served.c1, "app/lib/helper.py") is None
    assert store.read_file(KEY, served.c2, "app") is None
    assert store.read_file(KEY, served.c2, "README/x") is None
    assert store.folder_tree(KEY, served.c2, "app") == served.repo.rev(f"{served.c2}:app")
    assert store.folder_tree(KEY, served.c2, "README") is None
    assert store.folder_tree(KEY, served.c2, "nope") is None
    assert store.folder_tree("other/repo", served.c2, "app") is None


def test_export_folder_keeps_modes_and_symlinks(
    served: Served, store: GitStore, tmp_path: Path
) -> None:
    store.fetch(KEY, served.url)
    dest = tmp_path / "generations" / "app-1"

    tree = store.export_folder(KEY, served.c2, "app", dest)

    assert tree == store.folder_tree(KEY, served.c2, "app") == served.repo.rev(f"{served.c2}:app")
    files = sorted(str(p.relative_to(dest)) for p in dest.rglob("*") if not p.is_dir())
    assert files == ["lib/helper.py", "params.yaml", "run.sh", "start"]
    assert (dest / "params.yaml").read_text() == "speed: 2\n"
    assert (dest / "run.sh").stat().st_mode & 0o111 == 0o111
    assert not (dest / "params.yaml").stat().st_mode & 0o111
    assert (dest / "start").is_symlink() and os.readlink(dest / "start") == "run.sh"
    with pytest.raises(FileExistsError):
        store.export_folder(KEY, served.c2, "app", dest)


def test_export_of_an_absent_folder(served: Served, store: GitStore, tmp_path: Path) -> None:
    store.fetch(KEY, served.url)
    dest = tmp_path / "gen"
    with pytest.raises(RefNotFoundError, match="missing"):
        store.export_folder(KEY, served.c2, "missing", dest)
    assert not dest.exists()


# -- ambiguous abbreviations --------------------------------------------------------------


def _colliding_messages(tree: str, parent: str) -> Iterator[tuple[str, str]]:
    """Two commit messages whose commits (as `git commit-tree` writes them) share 4 digits."""
    ident = "{name} <{email}> 1704067200 +0000"
    author = ident.format(name=FIXED_ENV["GIT_AUTHOR_NAME"], email=FIXED_ENV["GIT_AUTHOR_EMAIL"])
    committer = ident.format(
        name=FIXED_ENV["GIT_COMMITTER_NAME"], email=FIXED_ENV["GIT_COMMITTER_EMAIL"]
    )
    seen: dict[str, str] = {}
    for i in range(1_000_000):
        message = f"probe {i}"
        body = (
            f"tree {tree}\nparent {parent}\nauthor {author}\ncommitter {committer}\n\n{message}\n"
        ).encode()
        sha = hashlib.sha1(b"commit %d\0" % len(body) + body).hexdigest()
        if sha[:4] in seen:
            yield seen[sha[:4]], message
            return
        seen[sha[:4]] = message


def test_ambiguous_abbreviation_names_the_candidates(served: Served, store: GitStore) -> None:
    tree = served.repo.rev(f"{served.c4}^{{tree}}")
    first, second = next(_colliding_messages(tree, served.c4))
    shas = [served.repo.git("commit-tree", tree, "-p", served.c4, "-m", m) for m in (first, second)]
    assert shas[0][:4] == shas[1][:4], "the collision search must match git's commit format"
    served.repo.branch("probe-a", shas[0])
    served.repo.branch("probe-b", shas[1])
    served.repo.push()
    store.fetch(KEY, served.url)

    with pytest.raises(RefNotFoundError) as caught:
        store.resolve_local(KEY, shas[0][:4])
    assert shas[0] in caught.value.message and shas[1] in caught.value.message
    assert store.resolve_local(KEY, shas[0][:12]) == shas[0]


# -- bounded reads --------------------------------------------------------------------------


def test_the_store_leaves_the_process_socket_timeout_alone(layout: Layout) -> None:
    before = socket.getdefaulttimeout()
    GitStore(layout, timeout=0.5)
    assert socket.getdefaulttimeout() == before  # library code does not change the process


def test_read_file_refuses_a_blob_larger_than_its_limit(served: Served, store: GitStore) -> None:
    big = "0123456789abcdef" * 4096  # 64 KiB
    served.repo.commit("big", {"big.txt": big})
    c6 = served.repo.commit("bigger", {"big.txt": big + "one more line\n"})  # a delta in the pack
    served.repo.push()
    store.fetch(KEY, served.url)

    content = (big + "one more line\n").encode()
    assert store.read_file(KEY, c6, "big.txt", limit=len(content)) == content
    with pytest.raises(GitError, match=r"'big.txt' at commit \w{12} is 65550 bytes") as caught:
        store.read_file(KEY, c6, "big.txt", limit=len(big))
    assert caught.value.hint
    assert store.read_file(KEY, served.c4, "README", limit=6) == b"three\n"


def test_read_file_does_not_inflate_a_huge_blob(served: Served, store: GitStore) -> None:
    huge = served.repo.commit("zeros", {"zeros.bin": "\0" * (16 * 1024 * 1024)})
    served.repo.push()
    store.fetch(KEY, served.url)

    tracemalloc.start()
    try:
        with pytest.raises(GitError, match="16777216 bytes"):
            store.read_file(KEY, huge, "zeros.bin")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * 1024 * 1024


def test_object_size_reads_every_kind_of_object_header(
    served: Served, store: GitStore, layout: Layout
) -> None:
    text = "".join(f"line {i}\n" for i in range(3000))
    served.repo.commit("text", {"text.txt": text})
    served.repo.commit("text edited", {"text.txt": text.replace("line 7\n", "line seven\n")})
    served.repo.push()
    store.fetch(KEY, served.url)
    checkout = layout.repository_dir(KEY)
    with Repo(str(checkout)) as repo:
        loose = Blob.from_string(b"loose\n" * 1000)
        repo.object_store.add_object(loose)  # written as a loose object
        shas = [*repo.object_store, loose.id]
        sizes = {sha: len(repo.object_store[sha].as_raw_string()) for sha in shas}
        assert {sha: object_size(repo.object_store, sha) for sha in shas} == sizes
    (index,) = (checkout / ".git/objects/pack").glob("*.idx")
    deltas = [line for line in git_out(checkout, "verify-pack", "-v", str(index)).splitlines()
              if re.match(r"[0-9a-f]{40} \w+ +\d+ \d+ \d+ \d+ [0-9a-f]{40}", line)]
    assert deltas, "the pack should hold deltas for the test to cover them"


def test_a_local_url_that_is_not_a_directory_is_refused_before_reading(
    store: GitStore, layout: Layout, tmp_path: Path
) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for url in ("/dev/zero", str(fifo)):
        with pytest.raises(GitError, match="not a directory"):
            store.fetch(KEY, url)
    assert_store_untouched(layout)


# -- fetch_objects: commits for the plan, checkouts untouched --------------------------------


def snapshot(checkout: Path) -> tuple[str, bytes, dict[str, bytes]]:
    """HEAD, the index file and every working-tree file: what fetch_objects must not move."""
    files = {str(p.relative_to(checkout)): p.read_bytes() for p in checkout.rglob("*")
             if p.is_file() and not p.is_symlink() and ".git" not in p.relative_to(checkout).parts}
    return (checkout / ".git/HEAD").read_text(), (checkout / ".git/index").read_bytes(), files


def test_fetch_objects_without_a_checkout_clones_without_checking_out(
    served: Served, store: GitStore, layout: Layout
) -> None:
    store.fetch_objects(KEY, served.url)

    assert store.head(KEY) is None
    assert store.origin_url(KEY) == served.url
    assert all(store.has_commit(KEY, c) for c in (served.c1, served.c2, served.c3, served.c4))
    assert os.listdir(layout.repository_dir(KEY)) == [".git"]
    assert not (layout.repository_dir(KEY) / ".git/index").exists()


def test_fetch_objects_from_the_origin_moves_refs_not_the_checkout(
    served: Served, store: GitStore, layout: Layout
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c2)
    checkout = layout.repository_dir(KEY)
    before = snapshot(checkout)
    c5 = served.repo.commit("fifth", {"README": "five\n"})
    served.repo.push()

    store.fetch_objects(KEY, served.url)

    assert store.has_commit(KEY, c5)
    assert git_out(checkout, "rev-parse", "origin/main") == c5
    assert snapshot(checkout) == before
    assert store.head(KEY) == served.c2


def test_fetch_objects_from_another_url_keeps_origin_and_its_refs(
    served: Served, store: GitStore, layout: Layout, make_repo: Callable[[str], RepoBuilder]
) -> None:
    store.fetch(KEY, served.url)
    store.checkout(KEY, served.c4)
    checkout = layout.repository_dir(KEY)
    before = snapshot(checkout)
    origin_refs = git_out(checkout, "for-each-ref", "refs/remotes", "refs/tags")
    fork = make_repo("fork/apps.git")
    forked = fork.commit("fork", {"README": "fork\n"})
    fork.tag("fork-v1")
    fork.push()

    store.fetch_objects(KEY, fork.bare.as_uri())

    assert store.has_commit(KEY, forked)
    assert store.origin_url(KEY) == served.url
    assert git_out(checkout, "for-each-ref", "refs/remotes", "refs/tags") == origin_refs
    assert git_out(checkout, "rev-parse", "refs/lpam/fetched/heads/main") == forked
    assert git_out(checkout, "rev-parse", "refs/lpam/fetched/tags/fork-v1") == forked
    assert snapshot(checkout) == before
    assert store.head(KEY) == served.c4
