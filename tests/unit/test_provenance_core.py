"""What a researcher checks of the timeline's reading (reconciler/core/provenance.py):
which generation ran at the instant of a log line, across switches, operator stops,
restarts, power cuts and a wall clock set hours late in the boot.

Times are built from the true time: `stamp(boot, mono, skew=...)` is the stamp lpam would
write `mono` seconds into a boot that truly began at `start`, with the car's wall clock
`skew` seconds off the truth (a Pi before GPS set it).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reconciler.core.provenance import (
    LOST,
    SUPERSEDED,
    Interval,
    at,
    intervals,
    moments,
    overlapping,
)
from schemas.timeline import Edge, Stamp

T0 = datetime(2026, 11, 20, 8, 0, tzinfo=timezone.utc)  # boot A truly began
T1 = T0 + timedelta(hours=3)  # boot B truly began
HOURS = 5 * 3600.0


def stamp(mono: float, *, boot: str = "A", start: datetime = T0, skew: float = 0.0) -> Stamp:
    return Stamp(boot=boot, mono=mono, wall=start + timedelta(seconds=mono + skew))


def true(seconds: float, start: datetime = T0) -> datetime:
    return start + timedelta(seconds=seconds)


def edge(kind: str, at_: Stamp, generation: str | None = None, *, how: str = "apply",
         app: str | None = "ctl", since: Stamp | None = None) -> Edge:
    return Edge.model_validate({"kind": kind, "how": how, "at": at_, "app": app,
                                "generation": generation, "since": since})


def running(found: list[Interval], when: datetime) -> list[str]:
    return [f"{i.app}:{i.generation}" for i in at(found, when)]


def test_two_generations_switched_mid_span() -> None:
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("ended", stamp(100), "g1"),
        edge("began", stamp(101), "g2"),
    ])
    assert [(i.generation, i.began.when) for i in found] == [("g1", true(10)),
                                                             ("g2", true(101))]
    first, second = found
    assert first.ended is not None and first.ended.when == true(100)
    assert (first.ended_how, first.ended.certainty) == ("apply", "recorded")
    assert second.ended is None and second.ended_how is None
    assert running(found, true(50)) == ["ctl:g1"]
    assert running(found, true(100.5)) == []  # the cutover's gap
    assert running(found, true(200)) == ["ctl:g2"]
    assert [i.generation for i in overlapping(found, true(90), true(110))] == ["g1", "g2"]


def test_an_operator_stop_is_a_gap() -> None:
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("ended", stamp(50), "g1", how="operator"),
        edge("began", stamp(80), "g1", how="operator"),
    ])
    assert [(i.began_how, i.ended_how) for i in found] == [("apply", "operator"),
                                                           ("operator", None)]
    assert running(found, true(49)) == ["ctl:g1"]
    assert running(found, true(60)) == []
    assert overlapping(found, true(55), true(75)) == []
    assert running(found, true(81)) == ["ctl:g1"]


def test_a_restart_stays_within_its_interval() -> None:
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("restarted", stamp(30), "g1", how="crashed"),
        edge("restarted", stamp(40), None, how="crashed"),  # no generation: the open one
        edge("ended", stamp(90), "g1"),
    ])
    assert len(found) == 1
    assert [m.when for m in found[0].restarts] == [true(30), true(40)]
    assert running(found, true(35)) == ["ctl:g1"]


def test_a_power_cut_across_boots_leaves_an_uncertain_end() -> None:
    last_seen = stamp(40)
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("clock", last_seen, how="clock", app=None),
        edge("ended", stamp(5, boot="B", start=T1), "g1", how=LOST, since=last_seen),
        edge("began", stamp(6, boot="B", start=T1), "g1"),
    ])
    first, second = found
    assert first.ended is not None and first.ended_how == LOST
    end = first.ended
    assert (end.certainty, end.earliest, end.latest, end.when) == (
        "uncertain", true(40), true(5, T1), true(40))
    assert running(found, true(30)) == ["ctl:g1"]
    assert running(found, true(3600)) == ["ctl:g1"]  # may still have run: in the window
    assert running(found, true(5.5, T1)) == []
    assert second.began.when == true(6, T1) and second.ended is None


def test_a_clock_set_hours_late_in_the_boot_corrects_the_earlier_stamps() -> None:
    edges = [
        edge("began", stamp(10, skew=-HOURS), "g1"),
        edge("restarted", stamp(20, skew=-HOURS + 1.0), "g1", how="crashed"),  # within 2 s
        edge("clock", stamp(60), how="clock", app=None),  # GPS set it
        edge("ended", stamp(100), "g1"),
    ]
    assert [(m.certainty, m.when) for m in moments(edges)] == [
        ("corrected", true(10)), ("corrected", true(20)), ("recorded", true(60)),
        ("recorded", true(100))]
    (found,) = intervals(edges)
    assert found.began.certainty == "corrected"
    assert found.began.earliest == found.began.latest == true(10)
    assert running([found], true(15)) == ["ctl:g1"]
    assert running([found], true(15) - timedelta(seconds=HOURS)) == []  # the wrong clock


def test_a_since_before_the_clock_was_set_is_corrected_by_its_boots_later_stamps() -> None:
    """The boot's reference is its latest stamp by boottime, not the last line naming it:
    a power-lost line written in the next boot names a moment from before GPS set the
    clock."""
    edges = [
        edge("began", stamp(10, skew=-HOURS), "g1"),
        edge("began", stamp(20, skew=-HOURS), "r1", app="recorder"),
        edge("clock", stamp(60), how="clock", app=None),
        edge("ended", stamp(5, boot="B", start=T1), "r1", how=LOST, app="recorder",
             since=stamp(30, skew=-HOURS)),
    ]
    found = intervals(edges)
    recorder = next(i for i in found if i.app == "recorder")
    assert recorder.ended is not None
    assert (recorder.ended.earliest, recorder.ended.latest) == (true(30), true(5, T1))
    assert found[0].began.when == true(10)


def test_a_small_drift_is_recorded_as_the_car_had_it() -> None:
    edges = [edge("began", stamp(10, skew=1.5), "g1"), edge("ended", stamp(20), "g1")]
    first, _ = moments(edges)
    assert (first.certainty, first.when) == ("recorded", true(11.5))


def test_an_interval_left_open_by_a_reboot_ends_with_its_boot() -> None:
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("clock", stamp(50), how="clock", app=None),
        edge("began", stamp(8, boot="B", start=T1, skew=-HOURS), "g2"),
        edge("clock", stamp(30, boot="B", start=T1), how="clock", app=None),
    ])
    first, second = found
    assert first.ended is not None and first.ended_how == LOST
    # after boot A's last stamp, before boot B's first (corrected by B's later clock)
    assert (first.ended.earliest, first.ended.latest) == (true(50), true(8, T1))
    assert first.ended.certainty == "uncertain"
    assert second.began.when == true(8, T1) and second.ended is None


def test_the_last_interval_of_an_earlier_boot_ends_even_with_nothing_after_it() -> None:
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("clock", stamp(3, boot="B", start=T1), how="clock", app=None),
    ])
    assert found[0].ended is not None
    assert (found[0].ended.earliest, found[0].ended.latest) == (true(10), true(3, T1))


def test_a_power_lost_line_after_the_next_began_closes_the_earlier_boots_interval() -> None:
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("began", stamp(4, boot="B", start=T1), "g1"),
        edge("ended", stamp(5, boot="B", start=T1), "g1", how=LOST, since=stamp(20)),
    ])
    first, second = found
    assert first.ended is not None and first.ended.earliest == true(20)
    assert second.ended is None  # the new boot's run is not the one that was lost


def test_a_began_over_an_open_interval_supersedes_it() -> None:
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("restarted", stamp(30), "g1", how="crashed"),
        edge("began", stamp(100), "g2"),  # g1's ended line was lost
    ])
    first, second = found
    assert first.ended_how == SUPERSEDED and first.ended is not None
    assert (first.ended.earliest, first.ended.when, first.ended.latest) == (
        true(30), true(100), true(100))
    assert first.ended.certainty == "uncertain"
    assert running(found, true(50)) == ["ctl:g1"]  # may have run: it was never seen ended
    assert running(found, true(100)) == ["ctl:g2"]
    assert second.began_how == "apply"


def test_apps_are_independent() -> None:
    found = intervals([
        edge("began", stamp(10), "g1"),
        edge("began", stamp(20), "r1", app="recorder"),
        edge("ended", stamp(30), "g1"),
    ])
    assert running(found, true(25)) == ["ctl:g1", "recorder:r1"]
    assert running(found, true(35)) == ["recorder:r1"]


def test_lost_and_odd_lines_are_ignored() -> None:
    naive = Stamp(boot="A", mono=20, wall=datetime(2026, 11, 20, 8, 0, 20))
    found = intervals([
        edge("ended", stamp(5), "g0"),  # its began was lost
        edge("restarted", stamp(6), "g0", how="crashed"),
        edge("began", stamp(7), None),  # no generation: not an interval
        edge("began", stamp(10), "g1"),
        edge("ended", stamp(15), "g9"),  # another generation: not this one's end
        edge("ended", naive, "g1"),
    ])
    (only,) = found
    assert only.ended is not None and only.ended.when == true(20)
    assert only.ended.when.tzinfo is not None
    assert intervals([]) == [] and moments([]) == []


@pytest.fixture
def far_local_time(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """A reader whose local time is not UTC (a laptop in California)."""
    monkeypatch.setenv("TZ", "America/Los_Angeles")
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


@pytest.mark.usefixtures("far_local_time")
def test_naive_times_are_utc_whatever_the_readers_zone() -> None:
    naive = [Stamp(boot="A", mono=m, wall=datetime(2026, 11, 20, 8, 0, m)) for m in (10, 20)]
    edges = [edge("began", naive[0], "g1"), edge("ended", naive[1], "g1")]
    edges.append(edge("clock", stamp(30), how="clock", app=None))  # an aware stamp
    assert [(m.certainty, m.when) for m in moments(edges)] == [
        ("recorded", true(10)), ("recorded", true(20)), ("recorded", true(30))]
    assert [i.generation for i in at(intervals(edges), datetime(2026, 11, 20, 8, 0, 15))] \
        == ["g1"]


def test_query_bounds() -> None:
    found = intervals([edge("began", stamp(10), "g1"), edge("ended", stamp(100), "g1")])
    assert overlapping(found, true(0), true(10)) == found  # began at the window's end
    assert overlapping(found, true(100), true(200)) == []  # ended at its start
    assert overlapping(found, true(99), true(200)) == found
    assert overlapping(found, true(50), true(0)) == found  # bounds in either order
    assert running(found, true(10)) == ["ctl:g1"]
    assert running(found, true(100)) == []
    assert running(found, true(9.9)) == []
    assert at(found, datetime(2026, 11, 20, 8, 0, 50)) == found  # naive: UTC


STATES = st.sampled_from([None, "g1", "g2", "g3"])


@settings(max_examples=200, deadline=None)
@given(spans=st.lists(st.tuples(STATES, st.integers(10, 5000)), min_size=1, max_size=12),
       skew=st.integers(-48, 48).filter(lambda h: h != 0), jump=st.floats(0, 1.0))
def test_at_returns_what_ran(spans: list[tuple[str | None, int]], skew: int,
                             jump: float) -> None:
    """Switches, stops and starts in one boot whose clock is set once, `skew` hours, at
    some moment: away from the edges, at(t) names exactly the generation that ran."""
    total = 5.0 + sum(length for _, length in spans)
    jump_at = 5.0 + jump * (total - 5.0)

    def wall(mono: float) -> Stamp:
        return stamp(mono, skew=skew * 3600.0 if mono < jump_at else 0.0)

    edges, truth, mono, state = [], [], 5.0, None
    for want, length in spans:
        if want != state and state is not None:
            edges.append(edge("ended", wall(mono), state))
        if want != state and want is not None:
            edges.append(edge("began", wall(mono + 1.0), want))
        state = want
        truth.append((true(mono + length / 2), want))
        mono += length
    edges.append(edge("clock", wall(jump_at), how="clock", app=None))
    edges.sort(key=lambda e: e.at.mono)
    found = intervals(edges)
    for when, want in truth:
        assert [i.generation for i in at(found, when)] == ([] if want is None else [want])
