"""The timeline's cost (issue 33): its size per month of a typical car, and what it adds
to an apply.

Size: a month of a typical car written through the real writer (engine/records/timeline.py)
— 100 drives, each a boot that closes the last drive's two apps as power-lost, starts them
again and sees the clock set by GPS, and one controller switch a day — with software as a
real app has it (60 pip packages). Reported: bytes on disk (open file, gzipped segments,
the software files), what the car publishes (timeline.json beside its status) and what a
push that carries it changed sends (git sends a new blob zlib-compressed, whole).

Apply: a switch between two scriptless apps under a real supervisord, in-process
(reconciler.workflow.applying.apply_file), in alternating rounds with the timeline on and
with its hook (engine/execution/context.py `note`) replaced by a no-op: the median of each
and their ratio, and the fsyncs each switch makes.

    .venv/bin/python -m bench.timeline [--rounds N]

Progress goes to stderr, a Markdown report to stdout (docs/benchmarks.md keeps one).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any
from unittest import mock

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from reconciler.engine.execution import context as context_module
from reconciler.engine.execution import provenance as provenance_module
from reconciler.engine.records.timeline import Timeline
from reconciler.workflow.applying import ApplyOptions, apply_file
from reconciler.workflow.machine import Machine
from reconciler.workflow.provenance import published_timeline
from schemas.timeline import Edge, Software, Stamp, params_digest
from tests.gitserver import GitDaemon, RepoBuilder

DRIVES = 100
DAYS = 30
PIP = [f"package-{n}==1.{n}.0" for n in range(60)]


def software(app: str, generation: str) -> Software:
    params = {"GAIN": generation[-2:], "RATE_HZ": "10"}
    return Software(app=app, generation=generation, repository="libpanda-default-apps",
                    commit="5f2c1e9" + "0" * 33, path=app, tree="a" * 40,
                    url="https://github.com/jmscslgroup/libpanda-default-apps",
                    commits={"libpanda-default-apps": "5f2c1e9" + "0" * 33},
                    params=params, params_digest=params_digest(params), pip=PIP,
                    lpam="0.1.0", desired_source="fleet@0123456789ab/vehicles/car-03.yaml",
                    desired_fingerprint="f" * 64, vehicle="2T3Y1RFV8KC014025")


def month(root: Path) -> dict[str, int]:
    """A month of a typical car, written edge by edge; bytes on disk and published."""
    timeline = Timeline(Layout(root))
    start = datetime(2026, 3, 1, 7, tzinfo=timezone.utc)
    controller = "ctl-000"
    for drive in range(DRIVES):
        day = drive * DAYS // DRIVES
        boot = f"boot-{drive}"
        wall = start + timedelta(days=day, hours=drive % 3 * 4)
        behind = wall - timedelta(hours=5)  # the Pi's clock until GPS sets it

        def at(mono: float, late: bool = True, b: str = boot,
               w: datetime = wall, e: datetime = behind) -> Stamp:
            return Stamp(boot=b, mono=mono, wall=(w if late else e) + timedelta(seconds=mono))

        if drive and drive * DAYS // DRIVES != (drive - 1) * DAYS // DRIVES:
            controller = f"ctl-{day:03d}"  # one switch a day
        for app, gen in (("recorder", "rec-001"), ("controller", controller)):
            if drive:
                timeline.append(Edge(kind="ended", how="power-lost", at=at(20, False),
                                     since=Stamp(boot=f"boot-{drive - 1}", mono=2400,
                                                 wall=wall - timedelta(hours=3)),
                                     app=app, generation=gen))
            digest = timeline.keep(software(app, gen))
            timeline.append(Edge(kind="began", how="apply", at=at(25, False), app=app,
                                 generation=gen, software=digest))
        timeline.append(Edge(kind="clock", how="clock", at=at(90), since=at(25, False)))
    files = [timeline.path, *timeline.segments.glob("*"),
             *(timeline.folder / "software").glob("*")]
    published = published_timeline(Layout(root), "car-03").content
    return {"edges": len(timeline.read().edges),
            "disk": sum(p.stat().st_size for p in files if p.is_file()),
            "published": len(published), "sent": len(zlib.compress(published))}


CATALOG = """\
apps:
  - name: one
    command: [python3, -u, idle.py]
    health: {settle_seconds: 0}
    properties:
      - owns_panda: true
  - name: two
    command: [python3, -u, idle.py]
    health: {settle_seconds: 0}
    properties:
      - owns_panda: true
"""
IDLE = "import time\nwhile True:\n    time.sleep(1)\n"


@contextmanager
def counted_fsyncs() -> Iterator[list[int]]:
    count = [0]
    real = os.fsync

    def fsync(fd: Any) -> None:
        count[0] += 1
        real(fd)

    with mock.patch.object(os, "fsync", fsync):
        yield count


def switches(work: Path, rounds: int) -> dict[str, list[float]]:
    """Seconds and fsyncs of each switch, with the timeline and without."""
    home = work / "home"
    home.mkdir(parents=True)
    out: dict[str, list[float]] = {"on": [], "off": [], "on fsyncs": [], "off fsyncs": []}
    with GitDaemon(work / "served", home=home) as daemon:
        repo = RepoBuilder(daemon.base, "car.git", work_root=work / "w", home=home)
        repo.write("libpanda-apps.yaml", CATALOG)
        for app in ("one", "two"):
            repo.write(f"{app}/idle.py", IDLE)
        repo.commit("two apps")
        repo.push()
        url = daemon.url("car.git")
        root = work / "root"
        machine = Machine.at(Layout(root), services="supervisor")
        path = root / "etc/lpam/desired-state.yaml"
        path.parent.mkdir(parents=True)
        try:
            for n in range(rounds * 2 + 1):
                app = ("one", "two")[n % 2]
                path.write_text(f"version: 2\nrepositories:\n  - url: {url}\n"
                                f"apps:\n  - name: {app}\n")
                mode = "on" if n % 4 in (1, 2) else "off"
                hook = provenance_module.note if mode == "on" else _nothing
                with mock.patch.object(context_module, "note", hook), \
                        counted_fsyncs() as fsyncs:
                    began = time.perf_counter()
                    apply_file(machine, path, options=ApplyOptions(),
                               confirm=lambda plan: True, report=lambda event: None)
                    took = time.perf_counter() - began
                if n:  # the first apply installs from nothing
                    out[mode].append(took)
                    out[f"{mode} fsyncs"].append(fsyncs[0])
                print(f"switch {n}: {mode} {took:.3f} s", file=sys.stderr)
        finally:
            shutdown(Layout(root))
    return out


def _nothing(*args: object) -> None:
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=6)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        sizes = month(Path(tmp) / "month")
        times = switches(Path(tmp) / "apply", args.rounds)
    med: Callable[[list[float]], float] = statistics.median
    print("| Timeline of one month (100 drives, a switch a day) | |\n|---|---:|")
    print(f"| edges | {sizes['edges']} |")
    print(f"| on disk (open file, segments, software) | {sizes['disk'] / 1024:.1f} KiB |")
    print(f"| published (timeline.json beside status.json) | {sizes['published'] / 1024:.1f} "
          "KiB |")
    print(f"| sent by a push that carries it changed (zlib, as git sends a blob) | "
          f"{sizes['sent'] / 1024:.1f} KiB |")
    print()
    print("| A switch between two apps (supervisord) | with the timeline | without | ratio |")
    print("|---|---:|---:|---:|")
    print(f"| median seconds ({len(times['on'])} rounds each) | {med(times['on']):.3f} | "
          f"{med(times['off']):.3f} | {med(times['on']) / med(times['off']):.2f}x |")
    print(f"| fsyncs per switch (median) | {med(times['on fsyncs']):.0f} | "
          f"{med(times['off fsyncs']):.0f} | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
