"""A checkout's config, refs and object names read from git's own files, without dulwich:
what the shim's reading flags need to resolve the desired state offline (a branch or tag
to the commit the last fetch saw) and to check each copy (`adapters.integrity`).

Place in the flow: `libpanda-app-manager -d/-l/-c/-t` (workflow/inventory.py) resolves the
default desired state through `adapters.objectfiles.ObjectFiles`, which asks this module
what a checkout's origin is and what its refs name; `adapters.integrity` asks it whether
the config parses and every ref names an object the store holds. Through dulwich that
costs its import (repository, refs, config, object store) on every read of the table, a
good share of the command on a Pi (issue 32). These files follow git's documented formats:

- `config`: `[section]` or `[section "subsection"]` headers, then `key = value` lines;
- a loose ref, `refs/...` (and `HEAD`): one line, 40 hex digits or `ref: <name>`;
- `packed-refs`: a `# pack-refs with: peeled ...` header, then `<40 hex> <name>` lines,
  each optionally followed by `^<40 hex>`, the commit an annotated tag peels to;
- a pack index of version 2 (`objects/pack/*.idx`): a fan-out table of 256 counts, the
  sorted object names, their CRCs, 4-byte offsets whose high bit points into a table of
  8-byte ones.

This is a fast path, not a second reader: it answers only what it read for certain, for
the plain checkouts git and lpam's store make, and raises `Unsure` for anything else —
a config line of another shape (quotes, escapes, comments, includes, extensions, settings
dulwich acts on when it opens a repository), a ref name or value out of the ordinary, a
symbolic ref naming another, a linked worktree, alternates, grafts, a multi-pack index.
The caller then asks dulwich, which answers as it always has. A ref both loose and packed
is read as git and dulwich read it: the loose one wins.
"""

from __future__ import annotations

import os
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from reconciler.adapters.objectsize import inflate_head

_SHA = 20
_IDX_MAGIC = b"\377tOc"
_FANOUT = 8  # where the fan-out table of a version-2 index starts
_HEX = re.compile(r"[0-9a-f]{40}")
_SYMREF = "ref: "
_PART = r"[A-Za-z0-9_-]+(?:\.[A-Za-z0-9_-]+)*"
_REF = re.compile(rf"refs(?:/{_PART}){{2,}}")  # every dulwich version reads these alike
_SECTION = re.compile(r'\[([a-z]+)(?: "([A-Za-z0-9_./:@+-]+)")?\]')
_SETTING = re.compile(r"([a-z]+)[ \t]*=[ \t]*([!$-:<-\[\]-~]+)")  # no ", #, ;, \ or space
_BOOL = {"true", "false"}
_KNOWN: dict[str, dict[str, set[str] | None]] = {
    # what git init, git clone and dulwich's Repo.init write; None: any plain value
    "core": {"repositoryformatversion": {"0"}, "filemode": _BOOL, "bare": {"false"},
             "logallrefupdates": _BOOL, "symlinks": _BOOL, "ignorecase": _BOOL},
    "remote": {"url": None, "fetch": None},
    "branch": {"remote": None, "merge": None},
}
_OBJECT_KINDS = (b"commit", b"tree", b"blob", b"tag")
_ODD_FILES = ("commondir", "info/grafts", "objects/info/alternates",
              "objects/pack/multi-pack-index", "reftable")

Config = dict[tuple[str, "str | None"], dict[str, str]]


class Unsure(Exception):
    """Not read for certain here: dulwich is asked instead."""


def config(git: Path) -> Config:
    """The settings of `git/config`, by (section, subsection), when every line is of the
    plain shape git and dulwich write and dulwich reads alike; else Unsure."""
    found: Config = {}
    settings: dict[str, str] | None = None
    allowed: dict[str, set[str] | None] = {}
    for line in (git / "config").read_text("ascii").splitlines():
        line = line.strip(" \t")
        if not line:
            continue
        header = _SECTION.fullmatch(line)
        if header is not None:
            section, sub = header.group(1), header.group(2)
            if section not in _KNOWN or (section == "core") != (sub is None) \
                    or (section, sub) in found:
                raise Unsure(f"config: [{section}]")
            settings, allowed = found.setdefault((section, sub), {}), _KNOWN[section]
            continue
        setting = _SETTING.fullmatch(line)
        if settings is None or setting is None:
            raise Unsure("config: a line of another shape")
        key, value = setting.group(1), setting.group(2)
        values = allowed.get(key, set())
        if key in settings or (values is not None and value not in values):
            raise Unsure(f"config: {key}")
        settings[key] = value
    return found


def plain(git: Path) -> Config:
    """The config of the checkout whose `.git` is `git`, when dulwich opens it as git does
    (its objects and refs where they always are, nothing it would read on opening besides
    the config): else Unsure."""
    if not (git / "objects").is_dir() or not (git / "refs").is_dir() \
            or any(os.path.lexists(git / name) for name in _ODD_FILES):
        raise Unsure("not a plain checkout")
    shallow = git / "shallow"
    if shallow.exists() and not all(_HEX.fullmatch(line)
                                    for line in shallow.read_text("ascii").splitlines()):
        raise Unsure("shallow")
    return config(git)


def origin_url(git: Path) -> str | None:
    """origin's URL in the config of a plain checkout (`plain`), None without one."""
    return plain(git).get(("remote", "origin"), {}).get("url")


@dataclass(frozen=True)
class Refs:
    """A checkout's refs as its files hold them: loose (HEAD included) and packed."""

    loose: dict[str, str]  # name -> 40 hex, or `ref: <name>`
    packed: dict[str, str]
    peeled: dict[str, str]  # packed name -> the commit an annotated tag peels to

    def names(self) -> list[str]:
        """Every ref, sorted (dulwich's `allkeys`)."""
        return sorted({*self.loose, *self.packed})

    def value(self, name: str) -> str | None:
        """What `name` names, a symbolic ref followed; None when it names nothing (a fresh
        clone's HEAD): dulwich's KeyError."""
        found = self.loose.get(name) or self.packed.get(name)
        if found is None or not found.startswith(_SYMREF):
            return found
        found = self.loose.get(found[len(_SYMREF):]) or self.packed.get(found[len(_SYMREF):])
        if found is not None and found.startswith(_SYMREF):
            raise Unsure(f"{name}: a symbolic ref naming another")
        return found

    def under(self, base: str) -> dict[str, str]:
        """Each ref under `base/` (its name there) and what it names; those that name
        nothing left out (dulwich's `as_dict`)."""
        names = {name[len(base) + 1:] for name in self.names() if name.startswith(base + "/")}
        values = {name: self.value(f"{base}/{name}") for name in names}
        return {name: value for name, value in values.items() if value is not None}

    def cached_peel(self, name: str) -> str | None:
        """What `packed-refs` says `name` peels to (dulwich's `get_peeled` of its refs:
        None for a loose ref, where the object must be read)."""
        if name not in self.packed:
            return None
        if name in self.loose:  # dulwich's answer then mixes the two files
            raise Unsure(f"{name}: both loose and packed")
        return self.peeled.get(name, self.packed[name])


def refs(git: Path) -> Refs:
    """Every ref of the checkout whose `.git` is `git` (`plain` first): Unsure for any
    name or value out of the ordinary."""
    loose: dict[str, str] = {}
    if os.path.islink(git / "HEAD"):
        raise Unsure("HEAD is a link")
    if os.path.exists(git / "HEAD"):
        loose["HEAD"] = _loose_ref(git / "HEAD")
    for folder, dirs, files in os.walk(git / "refs"):
        for name in [*dirs, *files]:
            if os.path.islink(os.path.join(folder, name)):
                raise Unsure("a ref that is a link")
        for file in files:
            name = Path(os.path.relpath(os.path.join(folder, file), git)).as_posix()
            if not _REF.fullmatch(name) or name.endswith(".lock"):
                raise Unsure(f"the ref name {name!r}")
            loose[name] = _loose_ref(git / name)
    packed, peeled = _packed(git / "packed-refs")
    return Refs(loose=loose, packed=packed, peeled=peeled)


def _loose_ref(path: Path) -> str:
    text = path.read_text("ascii")
    value = text[:-1] if text.endswith("\n") else text
    if _HEX.fullmatch(value) or (value.startswith(_SYMREF)
                                 and _REF.fullmatch(value[len(_SYMREF):])
                                 and not value.endswith(".lock")):
        return value
    raise Unsure(f"{path.name}: a value out of the ordinary")


def _packed(path: Path) -> tuple[dict[str, str], dict[str, str]]:
    if not path.exists():
        return {}, {}
    lines = path.read_text("ascii").split("\n")
    if lines[-1] != "" or not lines[0].startswith("# pack-refs with:") \
            or " peeled" not in lines[0]:
        raise Unsure("packed-refs without its header")
    packed: dict[str, str] = {}
    peeled: dict[str, str] = {}
    last: str | None = None
    for line in lines[1:-1]:
        if line.startswith("^") and last is not None and _HEX.fullmatch(line[1:]):
            peeled[last], last = line[1:], None
            continue
        sha, _, name = line.partition(" ")
        if not _HEX.fullmatch(sha) or not _REF.fullmatch(name) or name.endswith(".lock") \
                or name in packed:
            raise Unsure("packed-refs: a line of another shape")
        packed[name], last = sha, name
    return packed, peeled


def holder(git: Path) -> Callable[[bytes], bool]:
    """Whether the checkout certainly holds an object, as dulwich finds objects: loose,
    with the header of a known type, or in a pack `pack-*.pack` beside its index of
    version 2 (`plain` first), each index read once. False: not found here, which is not
    certain."""
    folder = git / "objects" / "pack"
    names = set(os.listdir(folder)) if folder.is_dir() else set()
    stems = [pack[:-len(".pack")] for pack in sorted(names) if pack.startswith("pack-")
             and pack.endswith(".pack") and pack[:-len(".pack")] + ".idx" in names]
    indexes: dict[str, bytes] = {}

    def index(stem: str) -> bytes:
        if stem not in indexes:
            data = (folder / (stem + ".idx")).read_bytes()
            if data[:8] != _IDX_MAGIC + b"\0\0\0\2":
                raise Unsure(f"{stem}.idx: an index not of version 2")
            indexes[stem] = data
        return indexes[stem]

    def holds(name: bytes) -> bool:
        text = name.hex()
        try:
            with open(git / "objects" / text[:2] / text[2:], "rb") as file:
                head = inflate_head(file.read)
        except FileNotFoundError:
            return any(index_offset(index(stem), name) is not None for stem in stems)
        kind, _, rest = head.partition(b" ")
        size, nul, _ = rest.partition(b"\0")
        return kind in _OBJECT_KINDS and bool(nul) and size.isdigit()

    return holds


def index_offset(index: bytes, name: bytes) -> int | None:
    """Where object `name` starts in the pack a version-2 `index` describes; None when the
    pack does not hold it."""
    first = name[0]
    low = struct.unpack_from(">L", index, _FANOUT + 4 * (first - 1))[0] if first else 0
    high, count = struct.unpack_from(">L", index, _FANOUT + 4 * first)[0], \
        struct.unpack_from(">L", index, _FANOUT + 4 * 255)[0]
    names = _FANOUT + 256 * 4
    while low < high:
        middle = (low + high) // 2
        found = index[names + middle * _SHA:names + (middle + 1) * _SHA]
        if found == name:
            offsets = names + count * (_SHA + 4)
            small = struct.unpack_from(">L", index, offsets + middle * 4)[0]
            if not small & 0x80000000:
                return int(small)
            large = offsets + count * 4 + (small & 0x7FFFFFFF) * 8
            return int(struct.unpack_from(">Q", index, large)[0])
        if found < name:
            low = middle + 1
        else:
            high = middle
    return None
