"""The fleet page drawn from a view (report/fleetpage.py): every car's state in words, the
summary's counts, the marks of the timelines, and text from the cars escaped."""

from __future__ import annotations

import re
from datetime import datetime, timedelta, timezone

from reconciler.report.fleetpage import MARKS, render
from reconciler.report.fleetview import CarView, FleetView, Mark, RevisionSummary, State

NOW = datetime(2026, 11, 28, 6, 0, tzinfo=timezone.utc)
SINCE = NOW - timedelta(days=30)


def car(vehicle: str, state: State, *marks: Mark, detail: str = "why") -> CarView:
    return CarView(vehicle=vehicle, state=state, detail=detail, revision="a" * 40,
                   apps=("ctl-a (running)",), gate=None, override=None,
                   reported=NOW - timedelta(minutes=12), marks=tuple(marks))


def view(*cars: CarView) -> FleetView:
    return FleetView(generated=NOW, tip="b" * 40, cars=cars, since=SINCE,
                     revisions=(RevisionSummary("b" * 40, 2, 1, 1, 0),),
                     rollout="waves car-03 → car-01, car-02 → *")


def test_every_car_shows_its_state_in_words_not_colour_alone() -> None:
    page = render(view(car("car-01", "confirmed"), car("car-02", "waiting"),
                       car("car-03", "rolled back"), car("car-04", "unknown")))
    for vehicle, state in (("car-01", "confirmed"), ("car-02", "waiting"),
                           ("car-03", "rolled back"), ("car-04", "unknown")):
        row = re.search(rf'<tr id="car-{vehicle}" data-state="{state}">(.*?)</tr>', page)
        assert row is not None, vehicle
        assert f"> {state}</td>" in row.group(1).replace("✓", "").replace("…", "") \
            .replace("↺", "").replace("?", "")
        assert "12 min ago" in row.group(1)
    assert 'content="width=device-width' in page  # a phone
    assert "<script" not in page and "http" not in page  # nothing to run, nothing to fetch
    assert "waves car-03 → car-01, car-02 → *" in page


def test_the_summary_counts_each_state_for_the_revision() -> None:
    page = render(view(car("car-01", "confirmed")))
    row = re.search(r'<tr><th scope="row"><code>bbbbbbbbbbbb</code></th>(.*?)</tr>', page)
    assert row is not None
    assert re.findall(r"<td>(\d+)</td>", row.group(1)) == ["2", "1", "1", "0"]


def test_a_timeline_marks_what_ran_and_each_rollback_with_its_words() -> None:
    ran = Mark(NOW - timedelta(days=2), NOW - timedelta(days=1), "ran", "ctl-b@4c1e2a3b9f00")
    back = Mark(NOW - timedelta(days=1), NOW - timedelta(days=1), "rollback",
                "rolled back: no CAN frames")
    page = render(view(car("car-03", "rolled back", ran, back)))
    svg = re.search(r'<svg data-vehicle="car-03" role="img".*?</svg>', page, re.S)
    assert svg is not None
    assert re.search(r'data-kind="ran"[^>]*><title>ctl-b@4c1e2a3b9f00: ', svg.group(0))
    assert re.search(r'data-kind="rollback"[^>]*><title>rolled back: no CAN frames: ',
                     svg.group(0))
    # it lies where it happened: a day before the end of a 30-day axis
    at = re.search(r'data-kind="rollback" d="M([\d.]+) ', svg.group(0))
    assert at is not None and abs(float(at.group(1)) - 1000 * 29 / 30) < 1


def test_a_crowded_timeline_keeps_every_rollback() -> None:
    many = [Mark(SINCE + timedelta(minutes=n), SINCE + timedelta(minutes=n), "deferral",
                 "deferred") for n in range(0, 30 * 1440, 7)]
    backs = [Mark(SINCE + timedelta(days=d), SINCE + timedelta(days=d), "rollback",
                  f"rolled back {d}") for d in range(1, 30)]
    page = render(view(car("car-07", "waiting", *sorted(many + backs,
                                                       key=lambda m: m.start))))
    assert page.count('data-kind="rollback"') == 29
    assert page.count('data-kind="deferral"') <= MARKS


def test_text_from_the_cars_is_escaped() -> None:
    hostile = "<script>alert(1)</script>"
    page = render(view(car("car-01", "waiting", Mark(NOW, NOW, "deferral", hostile),
                           detail=hostile)))
    assert hostile not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page
