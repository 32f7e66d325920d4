"""Where the timeline's edges come from: every change of the state record passes here.

The state record is written before and after every script (engine/execution/context.py),
so comparing the record before a write with the record after it is the one place that
sees every app begin and end, whoever asked (an apply's cutover, its rollback, an
operator's stop or start, the phone): no caller can forget to say it. An app counts as
running from the moment its start is intended (`starting`) to the moment its stop is done
(`installed`, or gone): an interval may say a little more than ran, never less, which is
the side a researcher's question needs.

At each begin lpam stores what runs (`Software`: commits, tree, parameters, the pip
environment as installed, ROS sources, lpam's version, the desired state) and rewrites the
app's provenance file, which the app's own environment names (LPAM_PROVENANCE).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler import __version__
from reconciler.base.atomic import write_atomic
from reconciler.base.boot import boot_id, boottime
from reconciler.base.layout import Layout
from reconciler.base.unit import UnitState
from reconciler.engine.records.timeline import Timeline
from schemas.record import ACTIVE, AppRecord, StateRecord
from schemas.timeline import Edge, How, Running, Software, Stamp, params_digest

if TYPE_CHECKING:
    from reconciler.engine.execution.context import Context

PIP_LIMIT = 2000  # distributions listed at most (a ROS environment has a few hundred)


def stamp_now(given: Callable[[], Stamp] | None, clock: Callable[[], datetime]) -> Stamp:
    """Now, as the timeline writes it: `given` (a test's), else this boot's id and
    boottime with the caller's wall clock."""
    return given() if given is not None else \
        Stamp(boot=boot_id(), mono=round(boottime(), 3), wall=clock())


def note(ctx: Context, before: StateRecord, after: StateRecord) -> None:
    """Write the edges of this change of the record: an app the record now shows active
    that the timeline does not (a start, from whatever state), and one the timeline shows
    running that the record no longer shows active (a stop). Compared with the timeline's
    own running.json, not with `before`: a look that closed an interval (a power cut) is
    followed by the start that opens the next, though the record said `running` all along."""
    if _statuses(before) == _statuses(after):
        return
    timeline = Timeline(ctx.layout)
    with timeline.locked():  # an apply's edges are written even if a look hangs on
        running = {r.app: r for r in timeline.running()}
        now = {a.name: a for a in after.apps if a.status in ACTIVE}
        ended = [r for r in running.values()
                 if r.app not in now or now[r.app].generation != r.generation]
        began = [a for a in now.values()
                 if a.name not in running or running[a.name].generation != a.generation]
        if ended or began:
            _note(ctx, timeline, after, running, ended, began)


def _statuses(record: StateRecord) -> set[tuple[str, str, str]]:
    return {(a.name, a.generation, a.status) for a in record.apps}


def _note(ctx: Context, timeline: Timeline, after: StateRecord, running: dict[str, Running],
          ended: list[Running], began: list[AppRecord]) -> None:
    """Ended first (a cutover stops the old app before it starts the new one), then began."""
    at = stamp_now(ctx.stamp, ctx.clock)
    for gone in ended:
        timeline.append(Edge(kind="ended", how=ctx.why, at=at, app=gone.app,
                             generation=gone.generation, software=gone.software))
        running.pop(gone.app, None)
        _mark_ended(timeline, gone.app, gone.generation, at)
    for app in began:
        software = software_for(ctx, app, after)
        digest = timeline.keep(software)
        timeline.append(Edge(kind="began", how=ctx.why, at=at, app=app.name,
                             generation=app.generation, software=digest))
        running[app.name] = Running(app=app.name, generation=app.generation, software=digest,
                                    unit=app.service, began=at, alive=at)
        write_atomic(timeline.app_file(app.name), _app_file(software, digest, at))
    timeline.write_running(list(running.values()))


def software_for(ctx: Context, app: AppRecord, record: StateRecord) -> Software:
    """What decides what `app` does, as installed now."""
    gen = ctx.folders.meta(app.name, app.generation) if ctx.folders is not None else None
    venv, ros = (gen.venv, dict(gen.ros)) if gen is not None else (None, {})
    repo = record.repository(app.repository)
    commits = {app.repository: app.commit, **{f"ros:{k}": v for k, v in ros.items()}}
    desired = ctx.desired
    return Software(
        app=app.name, generation=app.generation, repository=app.repository,
        commit=app.commit, path=app.path, tree=app.tree,
        url=repo.url if repo is not None else None, commits=commits,
        params=dict(app.params), params_digest=params_digest(app.params),
        command=app.command, launch=app.launch,
        pip=installed_pip(Path(venv)) if venv else [], ros=ros,
        lpam=__version__, desired_source=desired.source if desired else None,
        desired_fingerprint=desired.fingerprint if desired else None,
        vehicle=vehicle_id(ctx.layout.libpanda / "vin"), data=list(app.data))


def installed_pip(venv: Path) -> list[str]:
    """`name==version` of every distribution in the environment, from its metadata
    folders (what `pip freeze` reads, without starting pip: a second, not a millisecond)."""
    found: set[str] = set()
    for folder in _site_packages(venv):
        for meta in folder.glob("*.dist-info"):
            name, _, version = meta.name[: -len(".dist-info")].partition("-")
            if name and version:
                found.add(f"{name}=={version}")
            if len(found) >= PIP_LIMIT:
                break
    return sorted(found)


def _site_packages(venv: Path) -> Iterable[Path]:
    return sorted(venv.glob("lib/python3*/site-packages"))


def vehicle_id(path: Path) -> str | None:
    """The car's VIN as libpanda keeps it (`/etc/libpanda.d/vin`), if it does."""
    try:
        text = path.read_text(encoding="ascii", errors="replace").strip()
    except OSError:
        return None
    return text[:64] if text and text.isprintable() else None


def _app_file(software: Software, digest: str, began: Stamp) -> str:
    data = {"version": 1, "software": digest, "began": began.model_dump(mode="json"),
            **software.model_dump(mode="json")}
    return json.dumps(data, indent=1, sort_keys=True) + "\n"


def _mark_ended(timeline: Timeline, app: str, generation: str, at: Stamp) -> None:
    """The app's provenance file says its generation ended (an app that reads it late
    must not stamp a file with a generation that no longer runs)."""
    path = timeline.app_file(app)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    if isinstance(data, dict) and data.get("generation") == generation:
        data["ended"] = at.model_dump(mode="json")
        write_atomic(path, json.dumps(data, indent=1, sort_keys=True) + "\n")


def provenance_environment(ctx: Context, app: AppRecord) -> dict[str, str]:
    """What the app's processes are told of their provenance (their unit's environment):
    constant for one generation with one set of parameters, as the unit itself is."""
    return {"LPAM_GENERATION": app.generation, "LPAM_COMMIT": app.commit,
            "LPAM_REPOSITORY": app.repository, "LPAM_TREE": app.tree,
            "LPAM_PARAMS_DIGEST": params_digest(app.params),
            "LPAM_PROVENANCE": str(Timeline(ctx.layout).app_file(app.name))}


def watch(layout: Layout, record: StateRecord, state: Callable[[str], UnitState],
          at: Stamp) -> list[Edge]:
    """Look at what the timeline says runs, as the service manager sees it now, and write
    what happened since the last look: an interval of an earlier boot ended by a power
    cut (between its last `alive` and now), a unit its manager restarted (a crash), one
    that stopped without lpam (an exit), one the manager started again by itself (at boot,
    or after it gave up). Called by `lpam status`, each agent pass and each apply's start,
    so the next boot closes what a power cut left open. Returns the edges written."""
    timeline = Timeline(layout)
    written: list[Edge] = []
    if not timeline.running_path.exists() and not any(a.status in ACTIVE
                                                      for a in record.apps):
        return written  # nothing runs, nothing ran: a look writes nothing (a bare root)
    with timeline.locked() as mine:
        if not mine:
            return written  # another look is writing now; the next one sees it
        running = {r.app: r for r in timeline.running()}
        gone: dict[tuple[str, str], str | None] = {}
        for app in list(running.values()):
            seen = _look(app, record, state, at)
            written.extend(seen.edges)
            if seen.still is None:
                gone[(app.app, app.generation)] = running.pop(app.app).software
            else:
                running[app.app] = seen.still
        for installed in record.apps:
            if installed.name in running or installed.status not in ACTIVE:
                continue
            now = state(installed.service) if installed.service else None
            if now is not None and now.running:
                software = gone.get((installed.name, installed.generation))
                written.append(Edge(kind="began", how="manager", at=at, app=installed.name,
                                    generation=installed.generation, software=software,
                                    note=now.describe()))
                running[installed.name] = Running(
                    app=installed.name, generation=installed.generation, software=software,
                    unit=installed.service, pid=now.pid, restarts=now.restarts,
                    began=at, alive=at)
        jumped = _jumped(timeline.running(), at)
        if jumped is not None:
            written.insert(0, jumped)
        for edge in written:
            timeline.append(edge)
        timeline.write_running(list(running.values()))
    return written


JUMP = 2.0  # seconds wall - boottime may drift between two looks before it is a jump


def _jumped(running: list[Running], at: Stamp) -> Edge | None:
    """A clock edge when the wall clock was set since the last look of this boot (GPS,
    NTP): the later stamp by which every earlier one of the boot is corrected."""
    before = [r.alive for r in running if r.alive.boot == at.boot]
    if not before:
        return None
    last = max(before, key=lambda s: s.mono)
    moved = at.offset - last.offset
    if abs(moved) <= JUMP:
        return None
    return Edge(kind="clock", how="clock", at=at, since=last,
                note=f"the wall clock moved {moved:+.0f} s since the last look")


@dataclass(frozen=True)
class _Seen:
    edges: list[Edge]
    still: Running | None  # None: it ended


def _look(app: Running, record: StateRecord, state_of: Callable[[str], UnitState],
          at: Stamp) -> _Seen:
    if app.alive.boot != at.boot:
        return _Seen([_end(app, "power-lost", at)], None)
    installed = record.installed(app.app)
    if installed is None or installed.generation != app.generation or \
            installed.status not in ACTIVE:  # its end was not seen: between alive and now
        return _Seen([_end(app, "exited", at, "the state record no longer shows it running")],
                     None)
    state = state_of(app.unit) if app.unit else None
    if state is None or not state.known:
        return _Seen([], app.model_copy(update={"alive": at}))  # the scripts' word stands
    coming_back = state.active == "activating"  # its manager restarts it now
    if not state.running and not coming_back:
        return _Seen([_end(app, "exited", at, state.describe())], None)
    edges = []
    moved = app.pid is not None and state.pid != app.pid
    if moved or (app.restarts is not None and state.restarts > app.restarts):
        edges.append(Edge(kind="restarted", how="crashed", at=at, since=app.alive,
                          app=app.app, generation=app.generation, software=app.software,
                          note=f"pid {app.pid} → {state.pid}, {state.restarts} restarts"))
    return _Seen(edges, app.model_copy(update={"alive": at, "pid": state.pid,
                                                "restarts": state.restarts}))


def _end(app: Running, how: How, at: Stamp, note: str | None = None) -> Edge:
    return Edge(kind="ended", how=how, at=at, since=app.alive, app=app.app,
                generation=app.generation, software=app.software, note=note)
