"""`lpam fleet status` as the lab reads it: which file each car follows and how old its
last report is, measured against the clock passed in (workflow/fleet.py). Reading the
status branches of a real clone is tests/integration/test_fleet.py."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from reconciler.workflow.fleet import Vehicle, ago, as_json, as_table

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
    assert lines[0].split() == ["Vehicle", "Follows", "Applied", "Current", "App", "Running",
                                "Changed", "by", "Last", "pass", "Last", "report"]
    assert "vehicles/rav4-01.yaml" in lines[1] and lines[1].endswith("3 h ago")
    assert "desired-state.yaml" in lines[2] and lines[2].endswith("12 min ago")
    assert lines[3].split()[1] == "?" and lines[3].endswith("4 d ago")
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
