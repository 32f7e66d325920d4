"""Every damage a checkout of the store can suffer is named, and no read of a damaged
checkout escapes as anything but an LpamError (issue 18, item 10): the real GitStore on a
real clone, damaged file by file as a power cut or a failing SD card would."""

from __future__ import annotations

import os
import zlib
from collections.abc import Callable
from pathlib import Path

import pytest
from dulwich.objects import Blob
from dulwich.repo import Repo

from reconciler.adapters.git import GitStore
from reconciler.base.errors import LpamError, StoreDamagedError
from reconciler.base.layout import Layout
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import apps_repo

KEY = "apps"


def writable(path: Path) -> Path:
    path.chmod(0o644)
    return path


def _pack(git: Path) -> Path:
    [pack] = (git / "objects" / "pack").glob("*.pack")
    return writable(pack)


def _flip(path: Path, at: int) -> None:
    data = bytearray(writable(path).read_bytes())
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))


def _loose(git: Path) -> None:
    """A loose object whose file was cut short (push_file writes loose objects)."""
    with Repo(str(git.parent)) as repo:
        blob = Blob.from_string(b"status of rav4-07\n")
        repo.object_store.add_object(blob)
    sha = blob.id.decode()
    path = writable(git / "objects" / sha[:2] / sha[2:])
    path.write_bytes(zlib.compress(b"blob 18\0status")[:-6])


DAMAGES: dict[str, tuple[Callable[[Path], object], str]] = {
    "pack truncated": (lambda git: _pack(git).write_bytes(_pack(git).read_bytes()[:-300]),
                       ".pack does not match its checksum"),
    "pack byte flipped": (lambda git: _flip(_pack(git), _pack(git).stat().st_size // 2),
                          ".pack does not match its checksum"),
    "pack emptied": (lambda git: _pack(git).write_bytes(b""), ".pack is truncated (0 bytes)"),
    "pack header": (lambda git: _flip(_pack(git), 1), ".pack does not start like a git pack"),
    "index deleted": (lambda git: _pack(git).with_suffix(".idx").unlink(),
                      "which is not in the store (a pack or its index is gone)"),
    "pack deleted": (lambda git: _pack(git).unlink(),
                     "which is not in the store (a pack or its index is gone)"),
    "index byte flipped": (lambda git: _flip(_pack(git).with_suffix(".idx"), 600),
                           ".idx does not match its checksum"),
    "loose object cut": (_loose, "does not inflate"),
    "git index truncated": (lambda git: (git / "index").write_bytes(
        (git / "index").read_bytes()[:60]), "index does not match its checksum"),
    "HEAD deleted": (lambda git: (git / "HEAD").unlink(), "HEAD is missing"),
    "config garbage": (lambda git: (git / "config").write_bytes(b"[remote \"origin\n\x00"),
                       "config unreadable"),
}


@pytest.fixture
def store(tmp_path: Path, make_repo: Callable[[str], RepoBuilder],
          git_daemon: GitDaemon) -> tuple[GitStore, str]:
    """A checkout of the app repository of apps.py at its commit, as apply leaves it."""
    commit = apps_repo(make_repo("apps.git"))
    store = GitStore(Layout(tmp_path / "root"), timeout=10)
    store.fetch(KEY, git_daemon.url("apps.git"))
    store.checkout(KEY, commit)
    return store, commit


def test_a_sound_checkout_has_no_damage(store: tuple[GitStore, str]) -> None:
    """No false alarm: plan and apply ask this of every repository they use."""
    git_store, _ = store
    assert git_store.damage(KEY) is None and git_store.damage("absent") is None
    with Repo(str(git_store.location(KEY))) as repo:  # a loose object, as push_file writes
        repo.object_store.add_object(Blob.from_string(b"status of rav4-07\n"))
    assert git_store.damage(KEY) is None
    git_store.fetch("fresh", git_store.origin_url(KEY) or "")  # a clone never checked out
    assert git_store.damage("fresh") is None


@pytest.mark.parametrize("name", list(DAMAGES))
def test_each_damage_is_named_and_no_read_escapes(
    store: tuple[GitStore, str], tmp_path: Path, name: str,
) -> None:
    git_store, commit = store
    git = git_store.location(KEY) / ".git"
    breaks, said = DAMAGES[name]
    breaks(git)
    found = git_store.damage(KEY)
    assert found is not None and said in found, found
    reads: dict[str, Callable[[], object]] = {
        "head": lambda: git_store.head(KEY),
        "origin_url": lambda: git_store.origin_url(KEY),
        "has_commit": lambda: git_store.has_commit(KEY, commit),
        "resolve_local": lambda: git_store.resolve_local(KEY, commit[:7]),
        "local_edits": lambda: git_store.local_edits(KEY),
        "read_file": lambda: git_store.read_file(KEY, commit, "libpanda-apps.yaml"),
        "folder_tree": lambda: git_store.folder_tree(KEY, commit, "alpha"),
        "folder_files": lambda: git_store.folder_files(KEY, commit, "alpha"),
        "local_refs": lambda: git_store.local_refs(KEY),
        "export_folder": lambda: git_store.export_folder(KEY, commit, "alpha",
                                                         tmp_path / "gen"),
        "checkout": lambda: git_store.checkout(KEY, commit),
    }
    for what, read in reads.items():
        try:
            read()
        except StoreDamagedError as exc:
            assert exc.key == KEY and exc.damage == found, what
        except LpamError:
            pass  # e.g. RefNotFoundError: the commit reads as absent
        # anything else (ChecksumMismatch, zlib.error, AssertionError…) fails the test


def test_a_fetch_makes_its_pack_durable_before_refs_name_it(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The fetch child fsyncs the pack, its index and the folder their renames changed
    before it answers and the parent writes refs: a pack left in the page cache by a power
    cut comes back empty, and refs naming it are the damage above (run in this process, so
    that its fsyncs can be seen)."""
    from reconciler.adapters import wire

    repo = make_repo("apps.git")
    apps_repo(repo)
    dest = tmp_path / "clone"
    Repo.init(str(dest), mkdir=True).close()
    synced: list[str] = []
    real = os.fsync

    def fsync(fd: int) -> None:
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    wire.fetch(str(repo.bare), str(dest))
    packs = str(dest / ".git" / "objects" / "pack")
    # dulwich fsyncs each file under its temporary name, before renaming it into place
    pack = next(i for i, p in enumerate(synced) if p.startswith(packs) and p.endswith(".pack"))
    index = next(i for i, p in enumerate(synced) if p.startswith(packs) and ".idx" in p)
    assert synced[-1] == packs and pack < index < len(synced) - 1, synced


def test_a_pack_lpam_wrote_is_read_whole_only_once_it_changed(
    store: tuple[GitStore, str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A plan checks every repository before it reads one: the packs lpam fetched itself
    (checked as they were stored) are not read whole again while unchanged, so a plan of
    a repository with large packs does not read them all each time; a pack cut short is
    still found at once."""
    from reconciler.adapters import integrity

    git_store, _ = store
    git = git_store.location(KEY) / ".git"
    whole: list[Path] = []
    read = integrity._pack_trailer

    def counted(path: Path) -> tuple[int, bytes] | str:
        whole.append(path)
        return read(path)

    monkeypatch.setattr(integrity, "_pack_trailer", counted)
    assert git_store.damage(KEY) is None and whole == []  # fetched by lpam: not read whole
    (git / integrity.VERIFIED).unlink()  # as an older lpam left it
    assert git_store.damage(KEY) is None and len(whole) == 1
    pack = _pack(git)
    pack.write_bytes(pack.read_bytes()[:-300])
    assert git_store.damage(KEY) is not None
