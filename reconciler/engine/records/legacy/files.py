"""Reading an LPAM directory: the only I/O of `lpam import-lpam`.

First step of the import: `gather` reads the LPAM files under `/etc/libpanda.d` (texts,
folder names, git HEADs) into an `LpamFiles` and interprets nothing; `eras` and `notes`
then work on that snapshot alone, so each format's parser is tested on text. The names
of LPAM's files are defined here, as are the limits on what is read.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from reconciler.base.errors import ConfigError
from reconciler.base.reading import read_bounded

DEFAULT_ETC_DIR = Path("/etc/libpanda.d")
APP_FILE = "app"
CSV_MANIFEST = "app-manifest.csv"
YAML_MANIFEST = "app-manifest.yaml"
YAML_BACKUP = "app-manifest.yaml.bak"  # LPAM's copy of an era-3 manifest after migrating it
TOP_FILES = (YAML_MANIFEST, CSV_MANIFEST, APP_FILE, YAML_BACKUP)
MAX_BYTES = 1024 * 1024
HEX40 = re.compile(r"[0-9a-f]{40}")


@dataclass(frozen=True)
class Clone:
    """A clone LPAM made under `apps-repositories/<owner>/<repo>`."""

    owner: str
    repo: str
    head: str | None  # text of .git/HEAD; None when absent or unreadable
    commit: str | None = None  # the commit HEAD resolves to (a branch's ref, packed or not)


@dataclass(frozen=True)
class LpamFiles:
    """Everything `gather` read from an LPAM directory; the only input of `convert`."""

    etc_dir: Path
    texts: Mapping[str, str]  # path relative to etc_dir -> text
    apps: tuple[str, ...] = ()
    clones: tuple[Clone, ...] = ()
    has_apps_dir: bool = False


# --- reading (the only I/O) ---------------------------------------------------------------


def gather(etc_dir: Path) -> LpamFiles:
    """Read the LPAM files under `etc_dir`; nothing is interpreted here."""
    if not etc_dir.exists():
        raise ConfigError(
            "LPAM directory not found", path=etc_dir,
            hint=f"give the directory LPAM used, e.g. lpam import-lpam {DEFAULT_ETC_DIR}",
        )
    if not etc_dir.is_dir():
        raise ConfigError(
            "not a directory", path=etc_dir,
            hint=f"give LPAM's directory (normally {DEFAULT_ETC_DIR}), not a file in it",
        )
    texts = {name: _read(etc_dir / name) for name in TOP_FILES if (etc_dir / name).is_file()}
    apps_dir = etc_dir / "apps"
    apps = tuple(p.name for p in _subdirs(apps_dir))
    for app in apps:
        ros = apps_dir / app / "rosRepositories.csv"
        if ros.is_file():
            texts[f"apps/{app}/rosRepositories.csv"] = _read(ros)
    clones = tuple(
        Clone(owner.name, repo.name, head, _commit(repo, head))
        for owner in _subdirs(etc_dir / "apps-repositories")
        for repo in _subdirs(owner)
        for head in [_head(repo)]
    )
    return LpamFiles(etc_dir, texts, apps, clones, apps_dir.is_dir())


def _subdirs(directory: Path) -> list[Path]:
    if not directory.is_dir():
        return []
    try:
        entries = sorted(directory.iterdir())
    except OSError as exc:
        raise ConfigError(f"cannot list: {exc.strerror}", path=directory) from None
    return [p for p in entries if p.is_dir() and not p.name.startswith(".")]


def _read(path: Path) -> str:
    """A file's text; a FIFO, a device or a huge file is refused, never read (a FIFO hung
    the import, /dev/zero would fill memory)."""
    try:
        raw = read_bounded(path, limit=MAX_BYTES, what="LPAM file",
                           hint="an LPAM file is a small regular text file")
    except FileNotFoundError:
        raise ConfigError("file not found", path=path) from None
    if b"\x00" in raw:
        raise ConfigError("file is binary, not text", path=path, line=1, column=1)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(
            "file is not UTF-8 text", path=path, line=line, column=1, hint="save it as UTF-8"
        ) from None


def _head(clone: Path) -> str | None:
    try:
        return read_bounded(clone / ".git" / "HEAD", limit=4096).decode("utf-8")
    except (OSError, ConfigError, UnicodeDecodeError):
        return None


def _commit(clone: Path, head: str | None) -> str | None:
    """The commit the clone's HEAD is at: its branch's loose ref, else its line in
    packed-refs, else HEAD itself when detached. None when it cannot be told."""
    text = (head or "").strip()
    if not text.startswith("ref: "):
        return text if HEX40.fullmatch(text) else None
    ref = text[len("ref: "):]
    if ".." in ref or not ref.startswith("refs/heads/"):
        return None
    git = clone / ".git"
    try:
        loose = read_bounded(git / ref, limit=4096).decode("ascii").strip()
        return loose if HEX40.fullmatch(loose) else None
    except (OSError, ConfigError, UnicodeDecodeError):
        pass
    try:
        packed = read_bounded(git / "packed-refs", limit=MAX_BYTES).decode("utf-8", "replace")
    except (OSError, ConfigError):
        return None
    for line in packed.splitlines():
        sha, _, name = line.partition(" ")
        if name.strip() == ref and HEX40.fullmatch(sha):
            return sha
    return None


def comment_safe(text: str) -> str:
    """Text from disk made safe for a YAML comment line."""
    return text if text.isprintable() else repr(text)
