"""`lpam provenance`: which software ran while a data file was recorded (issue 33).

A researcher starts from the data: *this CAN log — which controller, at which commit,
with which parameters?* The answer joins two things lpam reads: the file's span, from the
content's own timestamps where the format is known (adapters/spans.py), and the car's
timeline, as intervals with how sure their times are (core/provenance.py). What cannot be
known is said, never guessed: a file from before the timeline begins, from another car
(its VIN differs), with no times of its own, or recorded while the car's clock was being
set (its timestamps may be on the wrong clock: both readings are given when they differ).
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Literal

from reconciler import __version__
from reconciler.adapters.spans import Span, finished, open_paths, span
from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.core.provenance import Interval, Moment, intervals, overlapping
from reconciler.engine.records.timeline import Lines, Timeline
from schemas.timeline import Edge, FileSpan, Ran, Sidecar, Software, When

# Imported inside functions: the fleet clone's reader (dulwich) loads only for --repo.

Verdict = Literal["ran", "nothing ran", "before lpam", "other vehicle", "no times",
                  "clock uncertain"]


@dataclass(frozen=True)
class Known:
    """A car's timeline as read: its intervals, what ran in them, and its clock jumps."""

    edges: list[Edge]
    found: list[Interval]
    software: dict[str, Software]
    vehicle: str | None
    unreadable: int = 0

    @property
    def begins(self) -> datetime | None:
        return min((i.began.earliest for i in self.found), default=None)

    def jumps(self) -> list[tuple[datetime, datetime, timedelta]]:
        """(from, to, by): the car's wall clock read `from`..`to` before it was set by `by`."""
        out = []
        for edge in self.edges:
            if edge.kind == "clock" and edge.since is not None:
                by = timedelta(seconds=edge.at.offset - edge.since.offset)
                start = edge.since.wall - timedelta(seconds=edge.since.mono)
                out.append((_utc(start), _utc(edge.at.wall - by), by))
        return out


@dataclass(frozen=True)
class Answer:
    """What ran during one file (or one moment)."""

    path: Path | None
    span: Span | None
    verdict: Verdict
    found: list[Interval] = field(default_factory=list)
    other: list[Interval] = field(default_factory=list)  # clock uncertain: the other reading
    said: str = ""


def known(timeline: Timeline) -> Known:
    """This car's timeline, from its files."""
    lines = timeline.read()
    digests = {e.software for e in lines.edges if e.software}
    return _known(lines, {d: s for d in digests if (s := timeline.software(d)) is not None})


def _known(lines: Lines, software: dict[str, Software]) -> Known:
    vehicles = {s.vehicle for s in software.values() if s.vehicle}
    return Known(lines.edges, intervals(lines.edges), software,
                 next(iter(vehicles)) if len(vehicles) == 1 else None, lines.unreadable)


def of_file(path: Path, car: Known) -> Answer:
    """What ran while `path` was recorded; ConfigError when there is no such file."""
    if not path.exists():
        raise ConfigError("no such file", path=path, hint="give the path of a data file")
    seen = span(path)
    if seen.vehicle and car.vehicle and seen.vehicle != car.vehicle:
        return Answer(path, seen, "other vehicle", said=f"recorded by vehicle "
                      f"{seen.vehicle}; this timeline is of {car.vehicle}")
    if seen.last is None:
        return Answer(path, seen, "no times", said="the file gives no times of its own")
    first = seen.first or seen.last
    answer = between(first, seen.last, car)
    return Answer(path, seen, answer.verdict, answer.found, answer.other, answer.said)


def between(start: datetime, end: datetime, car: Known) -> Answer:
    """What ran at any instant of [start, end]."""
    start, end = _utc(start), _utc(end)
    begins = car.begins
    if begins is None or end < begins:
        return Answer(None, None, "before lpam", said="before this car's timeline begins"
                      + (f" ({begins.isoformat(timespec='seconds')})" if begins else ""))
    found = overlapping(car.found, start, end)
    for low, high, by in car.jumps():
        if start <= high and end >= low:  # may have been stamped by the clock before it was set
            other = overlapping(car.found, start + by, end + by)
            if _keys(other) != _keys(found):
                return Answer(None, None, "clock uncertain", found, other, said=(
                    f"the car's clock was set by {by} while these times were recorded: "
                    "if they were written before it was set, the second reading holds"))
    if not found:
        return Answer(None, None, "nothing ran", said="no app ran then")
    return Answer(None, None, "ran", found)


def _keys(found: list[Interval]) -> set[tuple[str, str]]:
    return {(i.app, i.generation) for i in found}


def _utc(moment: datetime) -> datetime:
    return moment if moment.tzinfo is not None else moment.replace(tzinfo=timezone.utc)


def desired_for(found: list[Interval], car: Known) -> tuple[str, list[str]]:
    """A pinned desired state that installs what ran in `found` (one generation per app),
    and what it cannot pin. Refused (ValueError) when an app ran two ways (generations,
    or parameters) during the span: the caller asks for one moment instead."""
    by_app: dict[str, Interval] = {}
    for interval in found:
        seen = by_app.get(interval.app)
        if seen is not None and (seen.generation, seen.software) != \
                (interval.generation, interval.software):
            if seen.generation != interval.generation:
                two = f"generations ({seen.generation}, {interval.generation})"
            else:
                two = "ways (parameters " + ", ".join(
                    getattr(car.software.get(i.software or ""), "params_digest", "unknown")
                    for i in (seen, interval)) + f"; generation {seen.generation})"
            raise ValueError(f"{interval.app} ran two {two} during this span")
        by_app[interval.app] = interval
    lines = ["version: 2", "repositories:"]
    apps: list[str] = []
    caveats: list[str] = []
    keys: dict[tuple[str, str | None, str], Software] = {}
    for name, interval in sorted(by_app.items()):
        software = car.software.get(interval.software or "")
        if software is None:
            caveats.append(f"{name}: what generation {interval.generation} ran is not "
                           "recorded (it began before lpam kept a timeline)")
            continue
        keys.setdefault((software.repository, software.url, software.commit), software)
        apps += [f"  - name: {_q(name)}", f"    repository: {_q(software.repository)}"]
        if software.params:
            apps.append("    params: {" + ", ".join(f"{_q(k)}: {_q(v)}" for k, v in
                                                   sorted(software.params.items())) + "}")
        caveats += _unpinned(software)
    for (key, url, commit), _ in sorted(keys.items(), key=lambda kv: kv[0][0]):
        lines += [f"  - name: {_q(key)}", f"    url: {_q(url or key)}", f"    ref: {commit}"]
    return "\n".join([*lines, "apps:", *apps]) + "\n", caveats


def _unpinned(software: Software) -> list[str]:
    out = []
    if software.pip:
        out.append(f"{software.app}: its pip environment ({len(software.pip)} packages as "
                   "installed) is made again from the requirements at that commit; "
                   "versions not pinned there may differ")
    if software.ros:
        out.append(f"{software.app}: its ROS sources ran at " + ", ".join(
            f"{k}@{v[:12]}" for k, v in sorted(software.ros.items())) +
            "; they are pinned by the catalog at that commit, not by this file")
    if not software.url:
        out.append(f"{software.app}: the repository's URL was not recorded; write it in")
    return out


def _q(text: str) -> str:
    """A YAML scalar that reads back as exactly `text` (JSON strings are YAML)."""
    return json.dumps(text)


# --- words -----------------------------------------------------------------------------

SOURCES = {"csv": "its Time column", "candump": "its candump timestamps",
           "rosbag": "its bag index", "file-times": "the file's modification time only"}


def describe(answer: Answer, car: Known) -> list[str]:
    """An answer as `lpam provenance` prints it: the span, then each generation that ran,
    with how sure its times are; what is not known is said as such."""
    out = []
    if answer.path is not None:
        out.append(str(answer.path))
    if answer.span is not None and answer.span.last is not None:
        first = _when(answer.span.first) if answer.span.first else "?"
        out.append(f"  span: {first} .. {_when(answer.span.last)} "
                   f"(from {SOURCES[answer.span.source]})")
    if answer.said:
        out.append(f"  {answer.verdict}: {answer.said}")
    for label, found in (("ran", answer.found), ("or, on the clock before it was set, ran",
                                                  answer.other)):
        if found:
            out.append(f"  {label}:")
            out += [f"    {line}" for interval in found for line in _interval(interval, car)]
    return out


def _interval(interval: Interval, car: Known) -> list[str]:
    software = car.software.get(interval.software or "")
    what = (f"{software.repository}@{software.commit[:12]} {software.path or '.'}, params "
            f"{software.params_digest}" if software else "what ran is not recorded")
    ended = "still running" if interval.ended is None else (
        f"{_moment(interval.ended)} ({interval.ended_how})")
    lines = [f"{interval.app} {interval.generation} ({what})",
             f"  from {_moment(interval.began)} ({interval.began_how}) to {ended}"]
    if interval.restarts:
        lines.append(f"  restarted by its service manager {len(interval.restarts)} time"
                     f"{'' if len(interval.restarts) == 1 else 's'}")
    return lines


def _moment(moment: Moment) -> str:
    if moment.certainty == "uncertain":
        return f"between {_when(moment.earliest)} and {_when(moment.latest)}"
    mark = " [corrected: the car's clock was set later]" if moment.certainty == \
        "corrected" else ""
    return _when(moment.when) + mark


def _when(moment: datetime) -> str:
    return _utc(moment).astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def as_json(answer: Answer, car: Known) -> dict[str, object]:
    """An answer as `lpam provenance --json` prints it: the sidecar's fields (every moment
    with its certainty and bounds, each generation with what ran), the file's full path."""
    data = sidecar(answer, car).model_dump(mode="json")
    data["file"] = None if answer.path is None else str(answer.path)
    if answer.span is None:
        data["span"] = None
    data.pop("size")
    return data


def sidecar(answer: Answer, car: Known) -> Sidecar:
    """What travels with a data file: `<file>.provenance.json`."""
    seen = answer.span
    span = FileSpan(first=None, last=None, source="file-times") if seen is None else \
        FileSpan(first=seen.first, last=seen.last, source=seen.source, vehicle=seen.vehicle)
    size = 0
    if answer.path is not None:
        with contextlib.suppress(OSError):
            size = answer.path.stat().st_size
    return Sidecar(file="" if answer.path is None else answer.path.name, size=size,
                   span=span, verdict=answer.verdict, said=answer.said or None,
                   ran=[_ran(i, car) for i in answer.found],
                   or_ran=[_ran(i, car) for i in answer.other], vehicle=car.vehicle,
                   lpam=__version__)


def _ran(interval: Interval, car: Known) -> Ran:
    return Ran(app=interval.app, generation=interval.generation,
               software=car.software.get(interval.software or ""),
               began=_when_of(interval.began), began_how=interval.began_how,
               ended=None if interval.ended is None else _when_of(interval.ended),
               ended_how=interval.ended_how,
               restarts=[_when_of(m) for m in interval.restarts])


def _when_of(moment: Moment) -> When:
    return When(when=moment.when, earliest=moment.earliest, latest=moment.latest,
                certainty=moment.certainty)


# --- sidecars --------------------------------------------------------------------------

SUFFIX = ".provenance.json"
STAMP_BUDGET = 64  # files stamped per pass at most: a pass never waits on a backlog
SCAN_LIMIT = 20000  # files looked at per pass at most


def stamp_finished(layout: Layout, *, now: float, budget: int = STAMP_BUDGET) -> list[Path]:
    """Write `<file>.provenance.json` beside each finished data file that has none (or
    whose file grew since), in the folders the apps that ran declare (`data:`). Never
    inside a file an app owns, never one still written (libpanda's currentCan.csv points
    at it, it changed within a minute, or a process has it open). The stamped files."""
    car = known(Timeline(layout))
    globs = sorted({g for s in car.software.values() for g in s.data})
    written: list[Path] = []
    held = open_paths() if globs else frozenset()  # /proc read once per pass
    for path in _data_files(layout, globs):
        if len(written) >= budget:
            break
        side = path.with_name(path.name + SUFFIX)
        if _stamped(side, path) or not finished(
                path, now=now, current_link=layout.libpanda / "currentCan.csv", held=held):
            continue
        write_atomic(side, sidecar(of_file(path, car), car).model_dump_json(indent=1) + "\n")
        written.append(path)
    return written


def _data_files(layout: Layout, globs: list[str]) -> Iterator[Path]:
    seen = 0
    for pattern in globs:
        rooted = glob.escape(str(layout.root).rstrip("/")) + "/" + pattern.lstrip("/")
        for name in sorted(glob.glob(rooted)):
            seen += 1
            if seen > SCAN_LIMIT:
                return
            path = Path(name)
            if not name.endswith(SUFFIX) and path.is_file() and not path.is_symlink():
                yield path


def _stamped(side: Path, path: Path) -> bool:
    """A sidecar that covers the file as it is now (a file that grew is stamped again)."""
    try:
        return Sidecar.model_validate_json(side.read_bytes()).size == path.stat().st_size
    except (OSError, ValueError):
        return False


# --- for the fleet ---------------------------------------------------------------------

TIMELINE_FILE = "timeline.json"  # beside status.json on the fleet's status/<vehicle>
PUBLISHED_EDGES = 5000  # the newest edges published: a year of a car's drives, ~1.5 MB


@dataclass(frozen=True)
class Publishable:
    """What the car publishes of its timeline, and the mark that says it changed: the
    edges but its clock edges (a clock set alone waits for the next push; it changes no
    interval, only how sure their times are)."""

    content: bytes
    mark: str


def published_timeline(layout: Layout, vehicle: str) -> Publishable:
    """What the car publishes of its timeline: its newest edges, and what ran in them."""
    timeline = Timeline(layout)
    edges = timeline.read().edges[-PUBLISHED_EDGES:]
    digests = sorted({e.software for e in edges if e.software})
    software = {d: s for d in digests if (s := timeline.software(d)) is not None}
    lines = [e.model_dump(mode="json", exclude_none=True) for e in edges]
    data = {"version": 1, "vehicle": vehicle, "edges": lines,
            "software": {d: s.model_dump(mode="json") for d, s in software.items()}}
    mark = json.dumps([line for line in lines if line["kind"] != "clock"], sort_keys=True)
    return Publishable(
        (json.dumps(data, sort_keys=True, separators=(",", ":")) + "\n").encode("utf-8"),
        hashlib.sha256(mark.encode("utf-8")).hexdigest())


def known_published(content: bytes) -> Known:
    """A car's published timeline, read as the car reads its own."""
    data = json.loads(content)
    if not isinstance(data, dict) or data.get("version") != 1:
        raise ValueError("not a timeline this lpam reads")
    lines = Lines()
    for raw in data.get("edges", []):
        try:
            lines.edges.append(Edge.model_validate(raw))
        except ValueError:
            lines.unreadable += 1
    software = {}
    for digest, raw in dict(data.get("software", {})).items():
        with contextlib.suppress(ValueError):
            software[str(digest)] = Software.model_validate(raw)
    return _known(lines, software)


def from_fleet(repo: Path, vehicle: str | None) -> Known:
    """A car's timeline as it published it, from a clone of the fleet repository."""
    from reconciler.adapters import clone

    _, files = clone.published(repo, branch="main", prefixes=(
        b"refs/remotes/origin/status/", b"refs/heads/status/"), file=TIMELINE_FILE.encode())
    cars = {f.name: f for f in reversed(files)}  # the remote's branch first
    if vehicle is None and len(cars) == 1:
        vehicle = next(iter(cars))
    if vehicle is None or vehicle not in cars:
        listed = ", ".join(sorted(cars)) or "none"
        raise ConfigError(
            f"no published timeline of {vehicle}" if vehicle else
            "say which car's timeline to read", path=repo,
            hint=f"give --vehicle ID; the cars that published one: {listed} (fetch first: "
            "git fetch origin 'refs/heads/status/*:refs/remotes/origin/status/*')")
    try:
        return known_published(cars[vehicle].content)
    except ValueError as exc:
        raise ConfigError(f"the timeline of {vehicle} cannot be read: {exc}", path=repo,
                          hint="upgrade lpam: a newer one published it") from None
