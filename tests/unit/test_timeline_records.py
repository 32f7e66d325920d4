"""The timeline's files (engine/records/timeline.py) and the look at the service manager
(engine/execution/provenance.py `watch`): what a power cut, a crash, an exit and a clock
set leave on the timeline. The service manager here answers one question, `state`, from a
table the test sets; tests/integration/test_timeline.py and test_provenance.py ask a real
supervisord."""

from __future__ import annotations

import gzip
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from reconciler.base.layout import Layout
from reconciler.base.unit import UnitState
from reconciler.engine.execution.provenance import watch
from reconciler.engine.records import timeline as timeline_module
from reconciler.engine.records.timeline import Timeline
from schemas.record import AppRecord, StateRecord
from schemas.timeline import Edge, Running, Stamp

T0 = datetime(2026, 3, 14, 10, tzinfo=timezone.utc)


def at(mono: float, boot: str = "b1", skew: float = 0.0) -> Stamp:
    return Stamp(boot=boot, mono=mono, wall=T0 + timedelta(seconds=mono + skew))


class Units:
    """A service manager's `state`, answered from `self.states`."""

    def __init__(self) -> None:
        self.states: dict[str, UnitState] = {}

    def state(self, name: str) -> UnitState:
        return self.states.get(name, UnitState(name=name, known=False))


def record(status: str = "running") -> StateRecord:
    app = AppRecord(name="ctl", generation="g1", repository="r", commit="c" * 40,
                    tree="t" * 40, path="ctl", status=status, service="lpam-app-ctl")
    return StateRecord(apps=[app])


def running_since(timeline: Timeline, alive: Stamp, pid: int | None = 10) -> None:
    timeline.write_running([Running(app="ctl", generation="g1", software="s1",
                                    unit="lpam-app-ctl", pid=pid, restarts=0,
                                    began=at(1), alive=alive)])


def test_edges_read_back_in_order_and_a_torn_line_is_counted_not_guessed(tmp_path: Path
                                                                        ) -> None:
    timeline = Timeline(Layout(tmp_path))
    for n in range(3):
        timeline.append(Edge(kind="began", how="apply", at=at(n), app="ctl", generation=f"g{n}"))
    with timeline.path.open("a") as f:
        f.write('{"version":1,"kind":"ended","how":"ap')  # a power cut mid-line
    lines = timeline.read()
    assert [e.generation for e in lines.edges] == ["g0", "g1", "g2"]
    assert lines.unreadable == 1


def test_a_full_file_is_closed_into_a_segment_and_no_line_is_lost(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(timeline_module, "SEGMENT", 1000)
    timeline = Timeline(Layout(tmp_path))
    for n in range(40):
        timeline.append(Edge(kind="began", how="apply", at=at(n), app="ctl", generation=f"g{n}"))
    segments = sorted(timeline.segments.glob("*.jsonl.gz"))
    assert len(segments) >= 3
    assert all(gzip.decompress(s.read_bytes()).endswith(b"\n") for s in segments)
    assert [e.generation for e in timeline.read().edges] == [f"g{n}" for n in range(40)]


def test_an_interval_of_an_earlier_boot_ends_as_power_lost_between_alive_and_now(
        tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    timeline = Timeline(layout)
    running_since(timeline, at(50))
    units = Units()
    units.states["lpam-app-ctl"] = UnitState(name="lpam-app-ctl", known=True,
                                             active="inactive")
    [edge] = watch(layout, record(), units.state, at(5, boot="b2"))
    assert (edge.kind, edge.how, edge.since, edge.at.boot) == ("ended", "power-lost", at(50),
                                                               "b2")
    assert timeline.running() == []
    assert timeline.read().edges == [edge]


def test_a_new_pid_is_a_restart_and_a_stopped_unit_an_exit(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    timeline = Timeline(layout)
    running_since(timeline, at(50))
    units = Units()
    units.states["lpam-app-ctl"] = UnitState(name="lpam-app-ctl", known=True,
                                             active="active", pid=11, restarts=1)
    [edge] = watch(layout, record(), units.state, at(60))
    assert (edge.kind, edge.how, edge.since) == ("restarted", "crashed", at(50))
    assert timeline.running()[0].pid == 11
    assert watch(layout, record(), units.state, at(70)) == []  # the same pid: nothing new
    units.states["lpam-app-ctl"] = UnitState(name="lpam-app-ctl", known=True, active="failed")
    [edge] = watch(layout, record(), units.state, at(80))
    assert (edge.kind, edge.how, edge.since) == ("ended", "exited", at(70))
    assert timeline.running() == []


def test_the_clock_set_since_the_last_look_is_an_edge(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    timeline = Timeline(layout)
    running_since(timeline, at(50, skew=-5 * 3600))  # 5 h behind until GPS
    units = Units()
    units.states["lpam-app-ctl"] = UnitState(name="lpam-app-ctl", known=True,
                                             active="active", pid=10)
    [edge] = watch(layout, record(), units.state, at(60))
    assert (edge.kind, edge.since) == ("clock", at(50, skew=-5 * 3600))
    assert edge.since is not None
    assert edge.at.offset - edge.since.offset == pytest.approx(5 * 3600)
    assert watch(layout, record(), units.state, at(70)) == []  # once


def test_an_app_its_manager_started_by_itself_begins(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    units = Units()
    units.states["lpam-app-ctl"] = UnitState(name="lpam-app-ctl", known=True,
                                             active="active", pid=12)
    [edge] = watch(layout, record(), units.state, at(5, boot="b2"))
    assert (edge.kind, edge.how, edge.app) == ("began", "manager", "ctl")
    assert watch(layout, record("installed"), Units().state, at(9)) != []  # then its end
