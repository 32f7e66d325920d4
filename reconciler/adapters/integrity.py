"""Is a checkout of the repository store sound? The check behind `GitStore.damage`.

Place in the flow: `plan` and `apply` ask it of every repository before they read one
(engine/observe/targets.py), and `GitStore` asks it when a read of a checkout fails, to tell
damage (a truncated pack, flipped bytes, a lost index: what a power cut or a failing SD
card leaves) from a bug in lpam. The store is a cache of the remotes, so damage is not
repaired here: apply fetches the repository anew (`GitStore.renew`).

What is checked, from git's documented on-disk formats rather than through dulwich's
readers (those fail deep inside, with messages about mmaps and zlib, or not at all):

- each pack and its index (`objects/pack/*.pack`, `*.idx`): the pack's header, the SHA-1
  over its content that ends it, the index's own SHA-1, and the index naming that pack
  and as many objects. Every byte of every pack is read once: about 2 ms per MB here;
- each loose object: it inflates, and hashes to its name;
- every ref (HEAD included) names an object the store holds: a lost pack or index leaves
  refs pointing at nothing, and dulwich then reads the commit as absent, silently;
- the git index (`.git/index`) matches its checksum, and the config and refs parse.

Not checked: that every object a commit reaches is present (`git fsck --full` inflates
every object; a pack whose checksum holds is whole).

The config and the refs are read first from git's files (adapters/gitfiles.py), without
importing dulwich: the shim's reading flags check every copy before they list it (issue
32). What those files cannot tell for certain (a config or a ref out of the ordinary, a
ref naming an object not found there) is checked through dulwich as before, so the
answer, and the phrase naming what is wrong, are the same either way.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import struct
import zlib
from collections.abc import Callable
from pathlib import Path

from reconciler.adapters import gitfiles
from reconciler.base.atomic import write_atomic

# Imported inside functions: dulwich loads only where its parser is needed; `lpam status` and the
# shim's reading flags check copies without dulwich (tests/integration/test_imports.py).

_CHUNK = 1024 * 1024
_IDX_MAGIC = b"\377tOc"
_SHA = 20


def damage(checkout: Path) -> str | None:
    """What is wrong with the git checkout `checkout` in one short phrase (paths relative
    to its `.git`), or None when it is sound. Never raises for what it reads."""
    git = checkout / ".git"
    checks: tuple[tuple[str, Callable[[Path], str | None]], ...] = (
        ("config", _config), ("packs", _packs), ("loose", _loose), ("refs", _refs),
        ("index", _index))
    for name, check in checks:
        try:
            found = check(git)
        except Exception as exc:  # any failure to read is damage here
            found = f"{name} unreadable: {_reason(exc)}"
        if found is not None:
            return found
    return None


def _reason(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text[:120]}" if text else type(exc).__name__


def _config(git: Path) -> str | None:
    if not (git / "HEAD").is_file():
        return "HEAD is missing"
    try:
        gitfiles.config(git)  # a config of the plain shape dulwich certainly parses
        return None
    except Exception:  # gitfiles.Unsure, or unreadable: dulwich's parser decides
        pass
    from dulwich.config import ConfigFile

    ConfigFile.from_path(str(git / "config"))
    return None


VERIFIED = "lpam-verified.json"  # in .git: the packs lpam wrote, by size and time


def remember(checkout: Path) -> None:
    """Note the packs now in `checkout` as sound, by size and time: called right after
    lpam wrote them (a fetch, whose packs dulwich checked against their checksums as it
    stored them). While unchanged they are not read whole again: a plan of a repository
    with large packs (a ROS repository with bag files) must not read them all each time."""
    git = checkout / ".git"
    pack_dir = git / "objects" / "pack"
    stamps = {f"{stem}.pack": _stamp(pack_dir, stem) for stem in _indexed_packs(pack_dir)}
    with contextlib.suppress(OSError):
        write_atomic(git / VERIFIED, json.dumps(stamps, sort_keys=True) + "\n")


def _packs(git: Path) -> str | None:
    """Each pack against its checksum and its index; one lpam wrote (`remember`) is read
    whole only once its size or time (or its index's) changed — a pack cut short, or
    rewritten, changes them; what changes neither (a bit flipped in place) is found when a
    read of it fails."""
    pack_dir = git / "objects" / "pack"
    known = _verified(git)
    for stem in _indexed_packs(pack_dir):
        where = f"objects/pack/{stem}.pack"
        stamp = _stamp(pack_dir, stem)
        index = _index_trailer(pack_dir / f"{stem}.idx")
        if isinstance(index, str):
            return f"objects/pack/{stem}.idx {index}"
        path = pack_dir / f"{stem}.pack"
        pack = _pack_end(path) if known.get(path.name) == stamp else _pack_trailer(path)
        if isinstance(pack, str):
            return f"{where} {pack}"
        if index != pack:
            return f"{where} is not the pack its index describes (another pack's index, " \
                "or the pack was replaced)"
    return None


def _indexed_packs(pack_dir: Path) -> list[str]:
    """The names (without `.pack`) of the packs that have their index, sorted: a pack still
    being written has no index yet, and dulwich ignores it."""
    names = set(os.listdir(pack_dir)) if pack_dir.is_dir() else set()
    return [name[:-5] for name in sorted(names)
            if name.endswith(".pack") and name[:-5] + ".idx" in names]


def _stamp(pack_dir: Path, stem: str) -> list[int]:
    a, b = (pack_dir / f"{stem}.pack").stat(), (pack_dir / f"{stem}.idx").stat()
    return [a.st_size, a.st_mtime_ns, b.st_size, b.st_mtime_ns]


def _verified(git: Path) -> dict[str, list[int]]:
    try:
        data = json.loads((git / VERIFIED).read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): list(v) for k, v in data.items()} if isinstance(data, dict) else {}


def _pack_end(path: Path) -> tuple[int, bytes] | str:
    """(objects, checksum) from the header and trailer of a pack read whole before."""
    with path.open("rb") as file:
        header = file.read(12)
        file.seek(-_SHA, os.SEEK_END)
        stored = file.read(_SHA)
    if header[:4] != b"PACK" or len(stored) != _SHA:
        return "does not start like a git pack"
    return struct.unpack(">L", header[8:12])[0], stored


def _pack_trailer(path: Path) -> tuple[int, bytes] | str:
    """(objects, checksum) of a sound pack; else what is wrong with it."""
    size = path.stat().st_size
    if size < 12 + _SHA:
        return f"is truncated ({size} bytes)"
    digest = hashlib.sha1(usedforsecurity=False)
    with path.open("rb") as file:
        header = file.read(12)
        digest.update(header)
        left = size - 12 - _SHA
        while left > 0:
            chunk = file.read(min(_CHUNK, left))
            if not chunk:
                return "is shorter than it was a moment ago"
            digest.update(chunk)
            left -= len(chunk)
        stored = file.read(_SHA)
    if header[:4] != b"PACK" or struct.unpack(">L", header[4:8])[0] not in (2, 3):
        return "does not start like a git pack"
    if digest.digest() != stored:
        return "does not match its checksum (truncated or overwritten)"
    return struct.unpack(">L", header[8:12])[0], stored


def _index_trailer(path: Path) -> tuple[int, bytes] | str:
    """(objects, the pack's checksum) an index names, if the index is sound."""
    data = path.read_bytes()
    fanout_at = 8 if data[:4] == _IDX_MAGIC else 0
    if len(data) < fanout_at + 256 * 4 + 2 * _SHA:
        return f"is truncated ({len(data)} bytes)"
    if hashlib.sha1(data[:-_SHA], usedforsecurity=False).digest() != data[-_SHA:]:
        return "does not match its checksum (truncated or overwritten)"
    count = struct.unpack(">L", data[fanout_at + 255 * 4: fanout_at + 256 * 4])[0]
    return count, data[-2 * _SHA:-_SHA]


def _loose(git: Path) -> str | None:
    objects = git / "objects"
    for prefix in sorted(os.listdir(objects)) if objects.is_dir() else []:
        if len(prefix) != 2 or not (objects / prefix).is_dir():
            continue
        for rest in sorted(os.listdir(objects / prefix)):
            if len(rest) != 38:
                continue  # a temporary file of a write in progress
            raw = (objects / prefix / rest).read_bytes()
            try:
                content = zlib.decompress(raw)
            except zlib.error:
                return f"objects/{prefix}/{rest} does not inflate (truncated or overwritten)"
            if hashlib.sha1(content, usedforsecurity=False).hexdigest() != prefix + rest:
                return f"objects/{prefix}/{rest} does not hash to its name"
    return None


def _refs(git: Path) -> str | None:
    try:
        _refs_read(git)
        return None
    except Exception:  # gitfiles.Unsure, or unreadable: dulwich decides and names it
        pass
    from dulwich.repo import Repo

    with Repo(str(git.parent)) as repo:
        for name in sorted(repo.refs.allkeys()):
            try:
                sha = repo.refs[name]
            except KeyError:  # a branch HEAD names that was never made (a fresh clone)
                continue
            if sha not in repo.object_store:
                text = name.decode("utf-8", "replace")
                return f"{text} names {sha.decode('ascii')[:12]}, which is not in the " \
                    "store (a pack or its index is gone)"
    return None


def _refs_read(git: Path) -> None:
    """`_refs` from git's files: None when dulwich would open the checkout and find every
    ref's object; Unsure otherwise (damage included: dulwich's check then names it)."""
    gitfiles.plain(git)
    found, holds = gitfiles.refs(git), gitfiles.holder(git)
    for name in found.names():
        sha = found.value(name)
        if sha is not None and not holds(bytes.fromhex(sha)):
            raise gitfiles.Unsure(f"{name} names {sha}, not found here")


def _index(git: Path) -> str | None:
    path = git / "index"
    if not path.exists():
        return None
    data = path.read_bytes()
    if len(data) < 12 + _SHA or data[:4] != b"DIRC":
        return "index is truncated or not a git index"
    stored = data[-_SHA:]
    if stored != bytes(_SHA) and \
            hashlib.sha1(data[:-_SHA], usedforsecurity=False).digest() != stored:
        return "index does not match its checksum (truncated or overwritten)"
    return None
