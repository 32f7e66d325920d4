"""The fleet page opened in headless Chromium (Debian's package): what a lab manager sees
on a phone. The page of a real fleet is opened by tests/integration/test_waves.py; this one
opens a synthetic fleet of every state (bench/fleetpage.py) and an empty page to compare."""

from __future__ import annotations

import re
from pathlib import Path

from bench.fleetpage import synthetic
from reconciler.report.fleetpage import render
from reconciler.report.fleetview import FleetView
from tests.browser import PHONE, dom, png_colours, png_size, screenshot

RAN = (0x4A, 0x7F, 0xB5)  # report/fleetpage.py's `.ran` fill


def test_the_page_shows_every_car_state_in_text_and_its_timeline(tmp_path: Path) -> None:
    view = synthetic(8, 30, seed=3)
    page = tmp_path / "report" / "index.html"
    page.parent.mkdir()
    page.write_text(render(view), encoding="utf-8")
    built = dom(page, tmp_path / "browser")
    for car in view.cars:
        row = re.search(rf'<tr id="car-{car.vehicle}" data-state="{car.state}">(.*?)</tr>',
                        built, re.S)
        assert row is not None, car.vehicle
        assert car.state in re.sub("<[^>]+>", "", row.group(1))
        svg = re.search(rf'<svg data-vehicle="{car.vehicle}".*?</svg>', built, re.S)
        assert svg is not None and 'data-kind="ran"' in svg.group(0)
    shot = screenshot(page, tmp_path / "browser")
    assert png_size(shot)[0] == PHONE[0]  # the page fits a phone's width, no wider
    empty = tmp_path / "empty.html"
    empty.write_text(render(FleetView(generated=view.generated, tip=None, cars=(),
                                      revisions=(), rollout=None, since=view.since)))
    blank = screenshot(empty, tmp_path / "browser-empty")
    # the timelines are drawn (their bars are the page's one solid blue), and a page
    # with no car has none of it
    assert RAN in png_colours(shot)
    assert RAN not in png_colours(blank)
