"""The fleet page (reconciler/report/fleetpage.py) as a browser shows it: headless Chromium
opens a five-car page from a file, with no network, and its DOM holds each car's row with
its state in words and each car's timeline with its marks; a screenshot at a phone's size
(412 x 915) is the phone's width and is not blank.

Skipped where Chromium is not installed (Debian's `chromium`). The parsing checks, and
what the page says for each case, are tests/unit/test_fleet_page.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.fleetpage import synthetic
from reconciler.report.fleetpage import render
from reconciler.report.fleetview import FleetView
from tests import browser

STATE_GREEN = (0x1A, 0x7F, 0x37)  # fleetpage.py's --ok, the colour of "confirmed"


@pytest.fixture
def fleet() -> FleetView:
    return synthetic(5, 30, seed=7)  # the first four cars are in the four states


def page(tmp_path: Path, html: str, name: str = "fleet.html") -> Path:
    path = tmp_path / name
    path.write_text(html, encoding="utf-8")
    return path


def test_the_browser_shows_each_car_and_its_timeline(tmp_path: Path,
                                                     fleet: FleetView) -> None:
    dom = browser.dom(page(tmp_path, render(fleet)), tmp_path / "browser")
    assert '<html lang="en"><head>' in dom, dom[:200]  # serialized from the parsed DOM
    for car in fleet.cars:
        start = dom.index(f'<tr id="car-{car.vehicle}" data-state="{car.state}">')
        shown = dom[start:dom.index("</tr>", start)]
        assert f'class="state state-{car.state.replace(" ", "-")}"' in shown
        assert f"</span> {car.state}</span>" in shown  # the symbol, then the word
        begin = dom.index(f'data-vehicle="{car.vehicle}"')
        timeline = dom[begin:dom.index("</svg>", begin)]
        kinds = {m.kind for m in car.marks}
        for kind in kinds:
            assert f'data-kind="{kind}"' in timeline, (car.vehicle, kind)
        assert timeline.count("<title>") >= 1 + min(len(car.marks), 10)
    assert 'data-kind="rollback"' in dom  # the rolled-back car's last attempt
    assert "<script" not in dom


def test_a_phone_screenshot_is_drawn(tmp_path: Path, fleet: FleetView) -> None:
    shot = browser.screenshot(page(tmp_path, render(fleet)), tmp_path / "shot",
                              height=browser.PHONE[1])
    blank = browser.screenshot(page(tmp_path, "<!DOCTYPE html><title>blank</title>",
                                    "blank.html"), tmp_path / "blank",
                               height=browser.PHONE[1])
    assert browser.png_size(shot) == browser.PHONE
    drawn, empty = browser.png_colours(shot), browser.png_colours(blank)
    assert len(drawn) >= 16 and len(empty) <= 2  # text and colour against one white
    assert STATE_GREEN in drawn  # "✓ confirmed" of the first car, in its colour
