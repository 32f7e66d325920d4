"""Committed files read straight from a checkout's object files: the reads `lpam status`
makes (is a commit there, what a file held at a commit), without importing dulwich.

Place in the flow: `lpam status` (reconciler/report/gather.py) shows each repository's
catalog and each app's `description.txt` and `service` as committed. Through
`adapters.git.GitStore` that costs dulwich's import (its repository, index, config and
pack modules) on every status, a good share of the command on a Pi (issue 32); reading
these few objects needs git's documented formats only:

- a loose object, `objects/xx/<38 hex>`: one zlib stream, `<type> <size>\\0<content>`;
- a pack, `objects/pack/*.pack` with its version-2 index (`*.idx`: a fan-out table of 256
  counts, the sorted object names, their CRCs, 4-byte offsets whose high bit points into a
  table of 8-byte ones): at an offset, an entry header (type, size), then zlib data; a delta
  entry (OFS_DELTA: its base a relative offset back in the same pack; REF_DELTA: its base
  named) holds copy and insert instructions against its base; a pack is read only when
  its object count and closing checksum are those its index names (dulwich's own check
  before it reads a pack: a pack cut short fails it);
- a commit names its tree on its first line; a tree is entries `<octal mode> <name>\\0<20
  bytes>`.

This is a fast path, not a second store: it answers only what it found for certain. An
object it does not find (a lost pack, alternates, a format it does not know: an index of
version 1) and any read that fails (damage, a pack replaced under it by a fetch) are asked
again of `GitStore`, which answers them as it always has (its damage check, its
StoreDamagedError), at the price of dulwich's import on that path only. Like `GitStore`,
a symbolic link is never followed and a file larger than the limit is refused from its
header, before it is inflated.

The shim's reading flags (`libpanda-app-manager -d/-l/-c/-t`, workflow/inventory.py) also
resolve the default desired state offline through it, so it is the store the resolver
asks (the `Resolving` port): it checks each copy (`adapters.integrity`, as `GitStore.damage`
does), expands a full commit hash, and reads a checkout's origin and what the last fetch
saw of its branches and tags from git's config and ref files (adapters/gitfiles.py),
peeling an annotated tag by reading its object here. The same rule holds: anything not
read for certain, and every other operation of the port (the network, the writes), is
`GitStore`'s.
"""

from __future__ import annotations

import os
import re
import stat
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

from reconciler.adapters import gitfiles, integrity
from reconciler.adapters.objectsize import (
    delta_varint,
    entry_size,
    loose_size,
    packed_size,
    too_large,
)
from reconciler.base.errors import LpamError
from reconciler.engine.execution.ports import READ_LIMIT, Fetched, RemoteRefs
from schemas.names import is_hex_commit

if TYPE_CHECKING:
    from reconciler.adapters.git import GitStore
    from reconciler.base.layout import Layout

# Imported inside functions: GitStore (dulwich) is the fallback only; status and the shim read
# committed files without dulwich (start-up; tests/integration/test_imports.py).

_SHA = 20
_IDX_MAGIC = b"\377tOc"
_FANOUT = 8  # where the fan-out table of a version-2 index starts
_KINDS = {1: b"commit", 2: b"tree", 3: b"blob", 4: b"tag"}
_OFS_DELTA, _REF_DELTA = 6, 7
_CHUNK = 64 * 1024
_MAX_CHAIN = 10_000  # deltas on deltas: git's default depth is 50
_NAME = re.compile(r"[0-9a-f]{40}")
_MAX_PEEL = 100  # tags of tags


class _NotHere(Exception):
    """This path cannot answer for certain: `GitStore` is asked instead."""


class ObjectFiles:
    """`reconciler.report.gather.Objects` and the `Resolving` port over the store's
    checkouts, dulwich-free where it can be (module docstring); `GitStore` for the rest."""

    def __init__(self, layout: Layout) -> None:
        self._layout = layout
        self._store: GitStore | None = None
        self._packs: dict[str, list[_Pack]] = {}

    def location(self, key: str) -> Path:
        return self._layout.repository_dir(key)

    def has_commit(self, key: str, commit: str) -> bool:
        git = self._layout.repository_dir(key) / ".git"
        if not git.is_dir():
            return False
        try:
            if _NAME.fullmatch(commit):
                return self._object(key, git, bytes.fromhex(commit))[0] == b"commit"
        except LpamError:
            raise
        except Exception:  # _NotHere, or a read that failed: GitStore's answer
            pass
        return self._git().has_commit(key, commit)

    def read_file(self, key: str, commit: str, path: str, *,
                  limit: int = READ_LIMIT) -> bytes | None:
        """As `GitStore.read_file`: the regular file `commit:path`, at most `limit` bytes."""
        git = self._layout.repository_dir(key) / ".git"
        if not git.is_dir():
            return None
        try:
            return self._read(key, git, commit, path, limit)
        except LpamError:
            raise
        except Exception:  # _NotHere, or a read that failed: GitStore's answer
            return self._git().read_file(key, commit, path, limit=limit)

    def damage(self, key: str) -> str | None:
        """As `GitStore.damage`: what is wrong with the key's checkout; None when it is
        sound or absent (adapters.integrity, which reads the config and refs without
        dulwich where it can)."""
        path = self._layout.repository_dir(key)
        if not (path / ".git").is_dir():
            return None
        return integrity.damage(path)

    def origin_url(self, key: str) -> str | None:
        git = self._layout.repository_dir(key) / ".git"
        if not git.is_dir():
            return None
        try:
            return gitfiles.origin_url(git)
        except Exception:  # gitfiles.Unsure, or a read that failed: GitStore's answer
            return self._git().origin_url(key)

    def local_refs(self, key: str) -> RemoteRefs | None:
        """As `GitStore.local_refs`: what the last fetch saw of origin's branches and tags
        (peeled), from the ref files."""
        git = self._layout.repository_dir(key) / ".git"
        if not git.is_dir():
            return None
        try:
            return self._local_refs(key, git)
        except LpamError:
            raise
        except Exception:  # gitfiles.Unsure, _NotHere, or a read that failed
            return self._git().local_refs(key)

    def resolve_local(self, key: str, ref: str) -> str | None:
        """As `GitStore.resolve_local`; a full hash is looked up here, an abbreviated one
        (every object's name must be searched) by `GitStore`."""
        ref = ref.lower()
        if not is_hex_commit(ref):
            return None
        git = self._layout.repository_dir(key) / ".git"
        if not git.is_dir():
            return None
        try:
            if len(ref) == 40:
                gitfiles.plain(git)
                return ref if self._object(key, git, bytes.fromhex(ref))[0] == b"commit" \
                    else None
        except LpamError:
            raise
        except Exception:  # _NotHere, gitfiles.Unsure, or a read that failed
            pass
        return self._git().resolve_local(key, ref)

    # -- the rest of the port: GitStore's, unchanged ------------------------------------

    def head(self, key: str) -> str | None:
        return self._git().head(key)

    def local_edits(self, key: str) -> list[str]:
        return self._git().local_edits(key)

    def folder_tree(self, key: str, commit: str, folder: str) -> str | None:
        return self._git().folder_tree(key, commit, folder)

    def folder_files(self, key: str, commit: str, folder: str) -> list[str]:
        return self._git().folder_files(key, commit, folder)

    def folder_blobs(self, key: str, commit: str, folder: str) -> dict[str, str] | None:
        return self._git().folder_blobs(key, commit, folder)

    def ls_remote(self, url: str) -> RemoteRefs:
        return self._git().ls_remote(url)

    def fetch(self, key: str, url: str, *, want: str | None = None) -> Fetched:
        return self._git().fetch(key, url, want=want)

    def fetch_objects(self, key: str, url: str, *, want: str | None = None) -> Fetched:
        return self._git().fetch_objects(key, url, want=want)

    def renew(self, key: str, url: str) -> Path | None:
        return self._git().renew(key, url)

    def repoint(self, key: str, url: str) -> None:
        self._git().repoint(key, url)

    def checkout(self, key: str, commit: str) -> None:
        self._git().checkout(key, commit)

    def remove(self, key: str) -> None:
        self._git().remove(key)

    def export_folder(self, key: str, commit: str, folder: str, dest: Path) -> str:
        return self._git().export_folder(key, commit, folder, dest)

    def _local_refs(self, key: str, git: Path) -> RemoteRefs:
        url = gitfiles.origin_url(git)
        found = gitfiles.refs(git)
        refs = {"refs/heads/" + name: sha
                for name, sha in sorted(found.under("refs/remotes/origin").items())}
        for name, sha in sorted(found.under("refs/tags").items()):
            peeled = found.cached_peel("refs/tags/" + name)
            refs["refs/tags/" + name] = peeled if peeled is not None else \
                self._peel(key, git, sha)
        default = next((b for b in ("main", "master") if "refs/heads/" + b in refs), None)
        return RemoteRefs(url=url or "", refs=refs, default_branch=default)

    def _peel(self, key: str, git: Path, sha: str) -> str:
        """The object an annotated tag (of tags) names in the end; `sha` when not a tag."""
        for _ in range(_MAX_PEEL):
            kind, data = self._object(key, git, bytes.fromhex(sha))
            if kind != b"tag":
                return sha
            if not data.startswith(b"object ") or data[47:48] != b"\n" \
                    or not _NAME.fullmatch(data[7:47].decode("ascii")):
                raise _NotHere("a tag that does not name its object first")
            sha = data[7:47].decode("ascii")
        raise _NotHere("a chain of tags too long")

    def _git(self) -> GitStore:
        if self._store is None:
            from reconciler.adapters.git import GitStore

            self._store = GitStore(self._layout)
        return self._store

    def _read(self, key: str, git: Path, commit: str, path: str, limit: int) -> bytes | None:
        if not _NAME.fullmatch(commit):
            raise _NotHere(commit)
        kind, data = self._object(key, git, bytes.fromhex(commit))
        if kind != b"commit":
            return None
        if not data.startswith(b"tree "):
            raise _NotHere("a commit without its tree first")
        mode, name = stat.S_IFDIR, bytes.fromhex(data[5:45].decode("ascii"))
        for part in (p for p in path.split("/") if p not in ("", ".")):
            if not stat.S_ISDIR(mode):  # a file or a submodule on the way: no such path
                return None
            kind, tree = self._object(key, git, name)
            if kind != b"tree":
                return None
            found = _entry(tree, part.encode("utf-8"))
            if found is None:
                return None
            mode, name = found
        if not stat.S_ISREG(mode):  # a link is never followed
            return None
        size = self._size(key, git, name)
        if size > limit:
            raise too_large(key, path, commit, size, limit)
        kind, data = self._object(key, git, name)
        if kind != b"blob":
            raise _NotHere("a file entry that names no blob")
        return data

    def _size(self, key: str, git: Path, name: bytes) -> int:
        for pack in self._packs_of(key, git):
            offset = pack.offset(name)
            if offset is not None:
                return _known(packed_size(str(pack.path), offset, _SHA))
        return _known(loose_size(str(_loose(git, name))))

    def _object(self, key: str, git: Path, name: bytes) -> tuple[bytes, bytes]:
        """(type, content) of object `name`, from a pack or loose."""
        for pack in self._packs_of(key, git):
            offset = pack.offset(name)
            if offset is not None:
                return pack.read(offset, lambda base: self._object(key, git, base))
        try:
            raw = zlib.decompress(_loose(git, name).read_bytes())
        except FileNotFoundError:
            raise _NotHere(name.hex()) from None
        header, _, content = raw.partition(b"\0")
        kind, _, size = header.partition(b" ")
        if int(size) != len(content):
            raise _NotHere(f"{name.hex()}: not the size its header says")
        return kind, content

    def _packs_of(self, key: str, git: Path) -> list[_Pack]:
        if key not in self._packs:
            folder = git / "objects" / "pack"
            names = set(os.listdir(folder)) if folder.is_dir() else set()
            self._packs[key] = [_Pack(folder / name) for name in sorted(names)
                                if name.endswith(".pack") and name[:-5] + ".idx" in names]
        return self._packs[key]


def _loose(git: Path, name: bytes) -> Path:
    text = name.hex()
    return git / "objects" / text[:2] / text[2:]


def _known(size: int | None) -> int:
    if size is None:
        raise _NotHere("a size not read from its header")
    return size


def _entry(tree: bytes, wanted: bytes) -> tuple[int, bytes] | None:
    """(mode, name) of the entry `wanted` of a tree object's content."""
    at = 0
    while at < len(tree):
        space = tree.index(b" ", at)
        nul = tree.index(b"\0", space)
        if tree[space + 1:nul] == wanted:
            return int(tree[at:space], 8), tree[nul + 1:nul + 1 + _SHA]
        at = nul + 1 + _SHA
    return None


class _Pack:
    """One pack and its version-2 index, the index read once."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._index: bytes | None = None

    def offset(self, name: bytes) -> int | None:
        """Where object `name` starts in the pack; None when the pack does not hold it."""
        return gitfiles.index_offset(self._read_index(), name)

    def read(self, offset: int, named: Callable[[bytes], tuple[bytes, bytes]]
             ) -> tuple[bytes, bytes]:
        """(type, content) of the entry at `offset`; `named` reads a REF_DELTA's base."""
        deltas: list[bytes] = []
        with self.path.open("rb") as file:
            self._check(file)
            for _ in range(_MAX_CHAIN):
                file.seek(offset)
                head = file.read(64)
                kind = (head[0] >> 4) & 7
                size, at = entry_size(head)
                if kind == _OFS_DELTA:
                    byte = head[at]
                    back = byte & 0x7F
                    while byte & 0x80:
                        at += 1
                        byte = head[at]
                        back = ((back + 1) << 7) | (byte & 0x7F)
                    file.seek(offset + at + 1)
                    deltas.append(_inflate(file, size))
                    offset -= back
                    continue
                if kind == _REF_DELTA:
                    file.seek(offset + at + _SHA)
                    deltas.append(_inflate(file, size))
                    base_kind, data = named(head[at:at + _SHA])
                    break
                if kind not in _KINDS:
                    raise _NotHere(f"an entry of type {kind}")
                file.seek(offset + at)
                base_kind, data = _KINDS[kind], _inflate(file, size)
                break
            else:
                raise _NotHere("a chain of deltas too long")
        for delta in reversed(deltas):
            data = _patched(data, delta)
        return base_kind, data

    def _check(self, file: BinaryIO) -> None:
        """The pack is the one its index describes, as dulwich checks before it reads one:
        as many objects, the same checksum at its end. A pack cut short or emptied fails
        here, and GitStore names the damage."""
        index = self._read_index()
        header = file.read(12)
        file.seek(-_SHA, os.SEEK_END)
        if header[:4] != b"PACK" or header[8:12] != index[_FANOUT + 255 * 4:_FANOUT + 256 * 4] \
                or file.read(_SHA) != index[-2 * _SHA:-_SHA]:
            raise _NotHere(f"{self.path.name}: not the pack its index describes")

    def _read_index(self) -> bytes:
        if self._index is None:
            data = self.path.with_suffix(".idx").read_bytes()
            if data[:4] != _IDX_MAGIC or data[4:8] != b"\0\0\0\2":
                raise _NotHere(f"{self.path.name}: an index not of version 2")
            self._index = data
        return self._index


def _inflate(file: BinaryIO, size: int) -> bytes:
    """The zlib stream at the file's position, inflated: `size` bytes."""
    read = file.read
    inflater = zlib.decompressobj()
    out = []
    while not inflater.eof:
        chunk = read(_CHUNK)
        if not chunk:
            break
        out.append(inflater.decompress(chunk))
    data = b"".join(out)
    if not inflater.eof or len(data) != size:
        raise _NotHere("an entry not the size its header says")
    return data


def _patched(base: bytes, delta: bytes) -> bytes:
    """`base` with a delta's copy and insert instructions applied."""
    source, at = delta_varint(delta, 0)
    target, at = delta_varint(delta, at)
    if source != len(base):
        raise _NotHere("a delta against a base of another size")
    out = bytearray()
    while at < len(delta):
        op = delta[at]
        at += 1
        if op & 0x80:
            start = length = 0
            for bit in range(4):
                if op & (1 << bit):
                    start |= delta[at] << (8 * bit)
                    at += 1
            for bit in range(3):
                if op & (0x10 << bit):
                    length |= delta[at] << (8 * bit)
                    at += 1
            out += base[start:start + (length or 0x10000)]
        elif op:
            out += delta[at:at + op]
            at += op
        else:
            raise _NotHere("a delta instruction 0")
    if len(out) != target:
        raise _NotHere("a delta that makes an object of another size")
    return bytes(out)
