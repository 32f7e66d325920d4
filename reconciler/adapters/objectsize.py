"""The size of a git object, read from its header without inflating the object.

Place in the flow: `GitStore.read_file` (and `ObjectFiles.read_file`, status's reader of
committed files, adapters/objectfiles.py) asks for a blob's size before reading it, so
that a 600 MB file in an app repository is refused instead of being inflated into memory. dulwich
offers no size lookup (`get_raw` inflates the whole object, and a delta's base as well), so
this module reads git's documented on-disk formats directly:

- a loose object is a zlib stream that starts `<type> <size>\\0`: inflating its first bytes
  is enough;
- a packed object starts with a header holding its type and inflated size; for a delta
  (OFS_DELTA, REF_DELTA) that size is the delta's, and the object's own size is the second
  number in the delta's header, again in the first inflated bytes.

Anything unexpected (alternates, a format this code does not know, a damaged file) gives
None, and the caller falls back to reading the object and checking its length afterwards.
"""

from __future__ import annotations

import contextlib
import os
import zlib
from collections.abc import Callable
from typing import TYPE_CHECKING

from reconciler.base.errors import GitError

if TYPE_CHECKING:  # adapters/objectfiles.py reads sizes with this module, without dulwich
    from dulwich.object_store import BaseObjectStore
    from dulwich.objects import ObjectID

# Imported inside functions: dulwich's object store loads only when a size is not read from git's
# own files; objectfiles imports this module for status without dulwich (start-up).

_OFS_DELTA, _REF_DELTA = 6, 7
_HEAD_BYTES = 64  # more than any pack entry header, delta base offset or hash included
_INFLATED_HEAD = 32  # more than a loose header or the two sizes opening a delta
_MAX_INPUT = 64 * 1024  # compressed bytes read to find those first inflated bytes


def object_size(store: BaseObjectStore, sha: ObjectID) -> int | None:
    """The inflated size of object `sha` in `store`, or None when it cannot be read cheaply."""
    from dulwich.object_store import DiskObjectStore

    if not isinstance(store, DiskObjectStore):
        return None
    with contextlib.suppress(OSError, ValueError, zlib.error, IndexError):
        for pack in store.packs:
            try:
                offset = pack.index.object_offset(sha)
            except KeyError:
                continue
            return packed_size(os.fspath(pack.data.path), offset, len(sha) // 2)
        hexsha = sha.decode("ascii")
        return loose_size(os.path.join(os.fspath(store.path), hexsha[:2], hexsha[2:]))
    return None


def too_large(key: str, path: str, commit: str, size: int, limit: int) -> GitError:
    """The refusal of a file larger than a read's `limit`, said once for both readers."""
    return GitError(
        f"{key}: '{path}' at commit {commit[:12]} is {size} bytes; lpam reads at "
        f"most {limit} bytes of a file in a repository",
        hint="the file is too big to be an app catalog or parameter file; "
        "check that the right file is committed",
    )


def loose_size(path: str) -> int | None:
    with open(path, "rb") as file:
        head = inflate_head(file.read)
    kind, _, rest = head.partition(b" ")
    size, nul, _ = rest.partition(b"\0")
    return int(size) if kind and nul and size.isdigit() else None


def packed_size(path: str, offset: int, hash_size: int) -> int | None:
    with open(path, "rb") as file:
        file.seek(offset)
        head = file.read(_HEAD_BYTES)
        kind = (head[0] >> 4) & 7
        size, at = entry_size(head)
        if kind not in (_OFS_DELTA, _REF_DELTA):
            return size
        if kind == _OFS_DELTA:  # the base's offset: bytes up to the first without the high bit
            while head[at] & 0x80:
                at += 1
            at += 1
        else:
            at += hash_size
        file.seek(offset + at)
        delta = inflate_head(file.read)
    _source, at = delta_varint(delta, 0)
    target, _ = delta_varint(delta, at)
    return target


def inflate_head(read: Callable[[int], bytes]) -> bytes:
    """The first inflated bytes of the zlib stream `read` returns, inflating no more."""
    inflater = zlib.decompressobj()
    out = b""
    for _ in range(_MAX_INPUT // 4096):
        chunk = read(4096)
        out += inflater.decompress(inflater.unconsumed_tail + chunk, _INFLATED_HEAD - len(out))
        if len(out) >= _INFLATED_HEAD or inflater.eof or not chunk:
            break
    return out


def entry_size(head: bytes) -> tuple[int, int]:
    """A pack entry's inflated size and where its header ends: 4 bits after the type, then
    little-endian groups of 7 bits while the high bit says another byte follows."""
    if not head[0] & 0x80:
        return head[0] & 0x0F, 1
    rest, at = delta_varint(head, 1)
    return head[0] & 0x0F | rest << 4, at


def delta_varint(data: bytes, at: int) -> tuple[int, int]:
    """A size in a delta's header: little-endian groups of 7 bits."""
    value = shift = 0
    while True:
        byte = data[at]
        value |= (byte & 0x7F) << shift
        shift += 7
        at += 1
        if not byte & 0x80:
            return value, at
