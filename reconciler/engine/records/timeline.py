"""The timeline's files (`var/lib/lpam/timeline/`): what ran on this car, and when.

- `timeline.jsonl`: one fsynced JSON line per `Edge` (schemas/timeline.py), appended, never
  rewritten, as the apply journal is: a power cut loses at most the line being written,
  and a torn last line is skipped when read. Past SEGMENT bytes it is closed and gzipped
  into `segments/<n>.jsonl.gz` (an edge is a few hundred bytes; text compresses tenfold),
  so a year of a car's drives stays a few hundred KiB. Nothing is ever dropped silently: a
  timeline past LIMIT keeps its segments and says so (`Timeline.size_warning`).
- `software/<digest>.json`: each distinct `Software` once; edges name it by digest.
- `running.json`: the intervals that began and have not ended, with the unit's pid and
  restart count as last seen and the last moment each was known running (`alive`): what
  the next look at the service manager, or the next boot, compares with (a crash, an exit,
  a power cut), rewritten atomically.
- `apps/<app>.json`: the provenance of the generation running now, for the app itself
  (its environment's LPAM_PROVENANCE names it), so it can stamp its own files.

Writers are the engine (an app began or ended: engine/execution/provenance.py) and the
workflow's look at the service manager; readers are `lpam provenance` and the status
publisher. Edges from a newer lpam that this one cannot read are counted, never guessed.
"""

from __future__ import annotations

import contextlib
import gzip
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from pydantic import ValidationError

from migrations.registry import upgrade
from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ConfigError
from reconciler.base.flock import wait_exclusive
from reconciler.base.layout import Layout
from reconciler.base.reading import KIB, MIB, open_append, read_bounded
from schemas.kinds import DocumentKind
from schemas.timeline import Edge, Running, RunningFile, Software

SEGMENT = 256 * KIB  # the open file is closed into a gzipped segment past this size
LIMIT = 64 * MIB  # past this, lpam says the timeline needs attention (it never drops it)
READ_LIMIT = 32 * MIB  # one file (or one segment, unzipped) read at most
SOFTWARE_LIMIT = 4 * MIB
LOCK_WAIT = 10.0  # seconds a writer waits for another's read-modify-write of running.json


@dataclass
class Lines:
    """What was read: the edges, and how many lines this lpam could not read (torn by a
    power cut, or written by a newer lpam)."""

    edges: list[Edge] = field(default_factory=list)
    unreadable: int = 0


class Timeline:
    def __init__(self, layout: Layout) -> None:
        self.folder = layout.var / "timeline"
        self.path = self.folder / "timeline.jsonl"
        self.segments = self.folder / "segments"
        self.running_path = self.folder / "running.json"

    # --- writing -----------------------------------------------------------------------

    @contextlib.contextmanager
    def locked(self) -> Iterator[bool]:
        """Held around a read-modify-write of running.json: an apply's edges and a look
        at the service manager (`lpam status`, the agent) may come at once. Yields False
        when another writer held it for LOCK_WAIT seconds (the caller decides)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.folder / ".lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            yield wait_exclusive(fd, timeout=LOCK_WAIT)
        finally:
            os.close(fd)  # closing releases the lock

    def append(self, edge: Edge) -> None:
        """One edge, durably, before the caller goes on (the state record it explains is
        written right after)."""
        line = edge.model_dump_json(exclude_none=True) + "\n"
        fd = open_append(self.path, mode=0o644)
        try:
            os.write(fd, line.encode("utf-8"))
            os.fsync(fd)
            size = os.fstat(fd).st_size
        finally:
            os.close(fd)
        if size > SEGMENT:
            self._close_segment()

    def keep(self, software: Software) -> str:
        """Store `software` once; its digest, which edges name."""
        digest = software.digest
        path = self.folder / "software" / f"{digest}.json"
        if not path.exists():
            write_atomic(path, software.model_dump_json(indent=1) + "\n")
        return digest

    def app_file(self, app: str) -> Path:
        return self.folder / "apps" / f"{app}.json"

    def write_running(self, running: list[Running]) -> None:
        write_atomic(self.running_path, RunningFile(running=running).model_dump_json() + "\n")

    def _close_segment(self) -> None:
        self.segments.mkdir(parents=True, exist_ok=True)
        number = len(list(self.segments.glob("*.jsonl.gz"))) + 1
        target = self.segments / f"{number:06d}.jsonl.gz"
        data = self.path.read_bytes()
        write_atomic(target, gzip.compress(data, mtime=0))
        os.unlink(self.path)  # the segment holds every line: none is lost between the two

    # --- reading -----------------------------------------------------------------------

    def read(self) -> Lines:
        """Every edge, oldest first: the closed segments, then the open file."""
        lines = Lines()
        for segment in sorted(self.segments.glob("*.jsonl.gz")):
            try:
                raw = gzip.decompress(read_bounded(segment, limit=READ_LIMIT,
                                                   follow_symlinks=False, what="timeline"))
            except (OSError, ConfigError, EOFError):
                lines.unreadable += 1
                continue
            _parse(raw, lines, segment)
        try:
            raw = read_bounded(self.path, limit=READ_LIMIT, follow_symlinks=False,
                               what="timeline")
        except FileNotFoundError:
            return lines
        except ConfigError:
            lines.unreadable += 1
            return lines
        _parse(raw, lines, self.path)
        return lines

    def software(self, digest: str) -> Software | None:
        if not digest.isalnum():
            return None
        try:
            data = read_bounded(self.folder / "software" / f"{digest}.json",
                                limit=SOFTWARE_LIMIT, follow_symlinks=False, what="software")
            return Software.model_validate_json(data)
        except (OSError, ConfigError, ValidationError):
            return None

    def running(self) -> list[Running]:
        try:
            data = read_bounded(self.running_path, limit=MIB, follow_symlinks=False,
                                what="timeline")
            return RunningFile.model_validate_json(data).running
        except (OSError, ConfigError, ValidationError):
            return []

    def size(self) -> int:
        files = [self.path, *self.segments.glob("*.jsonl.gz")]
        return sum(p.stat().st_size for p in files if p.is_file())

    def size_warning(self) -> str | None:
        size = self.size()
        if size <= LIMIT:
            return None
        return (f"the timeline ({self.folder}) holds {size // MIB} MiB; lpam keeps every "
                "line: copy its segments elsewhere (they are what `lpam provenance` reads)")


def _parse(raw: bytes, lines: Lines, path: Path) -> None:
    for text in raw.decode("utf-8", "replace").splitlines():
        try:
            data = json.loads(text)
            edge = Edge.model_validate(upgrade(DocumentKind.TIMELINE, data, path=path))
        except (json.JSONDecodeError, RecursionError, ValidationError, ConfigError):
            lines.unreadable += 1  # torn by a power cut, or a newer lpam's
            continue
        lines.edges.append(edge)
