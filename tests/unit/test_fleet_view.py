"""`lpam fleet status` as the lab reads it: which file each car follows and how old its
last report is, measured against the clock passed in (workflow/fleet.py). Reading the
status branches of a real clone is tests/integration/test_fleet.py."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta, timezone

import pytest

from reconciler.report.fleetview import ago
from reconciler.workflow.fleet import Vehicle, as_json, as_table, state_of

NOW = datetime(2026, 11, 20, 15, 0, tzinfo=timezone.utc)
TIP = "c" * 40


def row(vehicle: str, *, seen: datetime, follows: str | None = "desired-state.yaml",
        ) -> Vehicle:
    return Vehicle(vehicle=vehicle, follows=follows, applied=TIP, up_to_date=True,
                   app="alpha", running=True, last_pass="nothing to do", reason=None,
                   last_seen=seen.isoformat(timespec="seconds"))


@pytest.mark.parametrize(("seconds", "said"), [
    (0, "0 s ago"), (59, "59 s ago"), (60, "1 min ago"), (3599, "59 min ago"),
    (3 * 3600 + 120, "3 h ago"), (47 * 3600, "47 h ago"), (49 * 3600, "2 d ago"),
    (-30, "0 s ago"),  # a few seconds of skew between two clocks is no news
    (-7200, "2 h ahead (the car's clock)"),
])
def test_an_age_as_people_say_it(seconds: float, said: str) -> None:
    assert ago(seconds) == said


def test_the_table_shows_the_file_each_car_follows_and_the_age_of_its_report() -> None:
    rows = [row("rav4-01", seen=NOW - timedelta(hours=3), follows="vehicles/rav4-01.yaml"),
            row("rav4-07", seen=NOW - timedelta(minutes=12)),
            row("rav4-09", seen=NOW - timedelta(days=4), follows=None)]  # an older lpam's
    lines = as_table(TIP, rows, now=NOW).splitlines()
    assert lines[0].split() == ["Vehicle", "State", "Follows", "Applied", "Current", "App",
                                "Running", "Changed", "by", "Last", "pass", "Last", "report"]
    assert "vehicles/rav4-01.yaml" in lines[1] and lines[1].endswith("3 h ago")
    assert "desired-state.yaml" in lines[2] and lines[2].endswith("12 min ago")
    assert lines[3].split()[2] == "?" and lines[3].endswith("4 d ago")
    assert [line.split()[1] for line in lines[1:4]] == ["confirmed", "confirmed", "unknown"]
    assert "  rav4-09 unknown: no report since" in lines[6]
    assert "heartbeat" in lines[-1]


def test_the_json_carries_the_file_and_the_age_by_the_given_clock() -> None:
    seen = NOW - timedelta(hours=3)
    report = as_json(TIP, [row("rav4-07", seen=seen)], now=NOW)
    (vehicle,) = report["vehicles"]
    assert vehicle["follows"] == "desired-state.yaml"
    assert (vehicle["age_seconds"], vehicle["age"]) == (3 * 3600, "3 h ago")
    assert vehicle["last_seen"] == "2026-11-20T12:00:00+00:00"
    later = as_json(TIP, [row("rav4-07", seen=seen)], now=NOW + timedelta(hours=1))
    assert later["vehicles"][0]["age"] == "4 h ago"  # the clock, not the wall, decides


def rolled(stage: str, **more: object) -> dict[str, object]:
    return {"revision": "e" * 40, "wave": 1, "stage": stage, "since": "2026-11-20T14:00:00",
            **more}


@pytest.mark.parametrize(("changes", "state", "said"), [
    ({}, "confirmed", "runs cccccccccccc, health checks passed"),
    ({"rollout": rolled("proven")}, "confirmed", "proven"),
    ({"rollout": rolled("proving", reason="ran it 60 s of 600 s")}, "confirmed",
     "proving it: ran it 60 s of 600 s"),
    ({"rollout": rolled("waiting", reason="wave 2 waits for wave 1")}, "waiting",
     "wave 2 waits for wave 1 (since 2026-11-20T14:00:00)"),
    ({"rollout": rolled("halted", reason="halted: car-03 (wave 1) rolled back")}, "waiting",
     "halted: car-03"),
    ({"last_pass": "deferred", "reason": "the car moves (12 km/h)"}, "waiting",
     "the car moves (12 km/h)"),
    ({"rollout": rolled("rolled back", reason="ctl-bad: health check failed")},
     "rolled back", "eeeeeeeeeeee failed: ctl-bad: health check failed; runs cccccccccccc"),
    ({"last_pass": "rolled back", "reason": "health"}, "rolled back", "failed: health"),
    ({"running": False}, "waiting", "alpha does not run"),
    ({"follows": None, "applied": None, "reason": "invalid car's status"}, "unknown",
     "cannot be read"),
])
def test_each_car_is_in_one_of_four_states_with_the_words_why(
        changes: dict[str, object], state: str, said: str) -> None:
    base = row("rav4-07", seen=NOW - timedelta(minutes=5))
    found = state_of(replace(base, **changes), NOW)  # type: ignore[arg-type]
    assert found[0] == state and said in found[1], found


def test_a_car_is_unknown_once_silent_for_longer_than_the_fleet_tolerates() -> None:
    quiet = row("rav4-07", seen=NOW - timedelta(hours=3))
    assert state_of(quiet, NOW)[0] == "confirmed"  # the default: 13 h
    state, said = state_of(quiet, NOW, silent=7200)  # a rollout's silent_seconds
    assert state == "unknown" and "no report since 2026-11-20T12:00:00" in said
    assert as_json(TIP, [quiet], now=NOW, silent=7200)["vehicles"][0]["state"] == "unknown"
