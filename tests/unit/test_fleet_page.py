"""The fleet page (reconciler/report/fleetpage.py) read back as a browser's parser reads it:
what a car says is shown, never interpreted; every car with its state in words; the
summary's counts; each rollback on its car's timeline with its reason. Chromium opening the
page is tests/integration/test_fleet_page_browser.py."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from html.parser import HTMLParser

from reconciler.report.fleetpage import render
from reconciler.report.fleetview import CarView, FleetView, Mark, RevisionSummary, State, ago

NOW = datetime(2026, 11, 20, 6, 0, tzinfo=timezone.utc)
SINCE = NOW - timedelta(days=30)
TIP = "0123456789abcdef" * 2 + "01234567"
VOID = {"meta", "br", "link", "img", "input", "hr", "col", "area", "base", "wbr"}


@dataclass
class Node:
    tag: str
    attrs: dict[str, str]
    children: list[Node] = field(default_factory=list)
    texts: list[str] = field(default_factory=list)  # its own and its descendants' text

    def text(self) -> str:
        return "".join(self.texts)

    def all(self, tag: str | None = None, **attrs: str) -> list[Node]:
        """Its descendants with this tag and these attributes (`data_kind` is data-kind)."""
        wanted = {k.replace("_", "-"): v for k, v in attrs.items()}
        found = []
        for child in self.children:
            if (tag is None or child.tag == tag) and \
                    all(child.attrs.get(k) == v for k, v in wanted.items()):
                found.append(child)
            found += child.all(tag, **attrs)
        return found

    def one(self, tag: str | None = None, **attrs: str) -> Node:
        found = self.all(tag, **attrs)
        assert len(found) == 1, (tag, attrs, len(found))
        return found[0]


class Tree(HTMLParser):
    """The page as a tree; an end tag that does not close the open element fails the test
    (the page must nest as it says)."""

    def __init__(self, page: str) -> None:
        super().__init__(convert_charrefs=True)
        self.root = Node("#document", {})
        self.open = [self.root]
        self.feed(page)
        self.close()
        assert self.open == [self.root], [n.tag for n in self.open]

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        node = Node(tag, {k: v or "" for k, v in attrs})
        self.open[-1].children.append(node)
        if tag not in VOID:
            self.open.append(node)

    def handle_startendtag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.open[-1].children.append(Node(tag, {k: v or "" for k, v in attrs}))

    def handle_endtag(self, tag: str) -> None:
        assert self.open[-1].tag == tag, (tag, [n.tag for n in self.open])
        self.open.pop()

    def handle_data(self, data: str) -> None:
        for node in self.open:
            node.texts.append(data)


def car(vehicle: str, state: State = "confirmed", *, marks: tuple[Mark, ...] = (),
        reported: datetime | None = NOW - timedelta(minutes=12), detail: str = "fine",
        ) -> CarView:
    return CarView(vehicle=vehicle, state=state, detail=detail, revision=TIP,
                   apps=("alpha (running)",), gate=None, override=None, reported=reported,
                   marks=marks)


def view(*cars: CarView, revisions: tuple[RevisionSummary, ...] = (),
         rollout: str | None = None) -> FleetView:
    return FleetView(generated=NOW, tip=TIP, cars=cars, revisions=revisions,
                     rollout=rollout, since=SINCE)


def tree(fleet: FleetView) -> Node:
    return Tree(render(fleet)).root


def row(page: Node, vehicle: str) -> Node:
    return page.one("tr", id=f"car-{vehicle}")


def at(days: float) -> datetime:
    return SINCE + timedelta(days=days)


HOSTILE = '<script>alert(1)</script>" onclick="x'


def test_what_a_car_says_is_shown_not_interpreted() -> None:
    marks = (Mark(at(1), at(2), "ran", f"{HOSTILE}@g1"),
             Mark(at(3), at(3), "rollback", f"reason {HOSTILE}"))
    page = render(view(car(HOSTILE, marks=marks, detail=HOSTILE)))
    assert "<script" not in page.lower()
    assert 'onclick="x' not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;&quot; onclick=&quot;x" in page
    document = Tree(page).root
    assert not document.all("script")
    shown = row(document, HOSTILE)  # the id holds the name whole, and nothing else
    assert "onclick" not in shown.attrs
    assert shown.one("th").text() == HOSTILE
    assert shown.all("td")[1].text() == HOSTILE  # the detail
    timeline = document.one("svg", data_vehicle=HOSTILE)
    assert HOSTILE in timeline.one("rect", data_kind="ran").one("title").text()
    assert f"reason {HOSTILE}" in timeline.one("g", data_kind="rollback").text()


def test_control_characters_are_replaced() -> None:
    page = render(view(car("car\x1b[31m-01\x00", detail="bell\x07")))
    assert not re.search(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]", page)
    assert 'id="car-car?[31m-01?"' in page
    assert "bell?" in page


def test_every_car_appears_with_its_state_in_words() -> None:
    states: dict[str, State] = {"c1": "confirmed", "c2": "waiting", "c3": "rolled back",
                                "c4": "unknown", "c5": "confirmed"}
    page = tree(view(*(car(v, s) for v, s in states.items())))
    rows = page.one("section", id="cars").all("tr")[1:]
    assert [r.attrs["id"] for r in rows] == [f"car-{v}" for v in states]
    for vehicle, state in states.items():
        shown = row(page, vehicle)
        assert shown.attrs["data-state"] == state
        cell = shown.one("span", **{"class": f"state state-{state.replace(' ', '-')}"})
        assert cell.text().split(maxsplit=1)[1] == state  # a symbol, then the word
        assert page.one("svg", data_vehicle=vehicle)  # and its timeline


def test_the_summary_counts_each_revision() -> None:
    revisions = (RevisionSummary(TIP, confirmed=7, waiting=2, failed=1, unknown=3),
                 RevisionSummary("f" * 40, confirmed=0, waiting=4, failed=0, unknown=0))
    section = tree(view(car("c1"), revisions=revisions)).one("section", id="revisions")
    headers = [(h.text(), h.attrs.get("scope")) for h in section.one("thead").all("th")]
    assert headers == [("Revision", "col"), ("Confirmed", "col"), ("Waiting", "col"),
                       ("Failed (rolled back)", "col"), ("Unknown", "col"),
                       ("Total", "col")]
    body = section.one("tbody").all("tr")
    assert [[c.text() for c in r.children] for r in body] == [
        [TIP[:12], "7", "2", "1", "3", "13"], ["f" * 12, "0", "4", "0", "0", "4"]]
    assert all(r.children[0].attrs == {"scope": "row"} for r in body)


def test_a_rollback_is_marked_with_its_reason() -> None:
    marks = (Mark(at(1), at(5), "ran", "alpha@g1"), Mark(at(5), None, "ran", "alpha@g2"),
             Mark(at(5.1), at(5.1), "rollback", "g2 failed its health check"),
             Mark(at(6), at(6), "deferral", "gate moving"))
    page = tree(view(car("c1", "rolled back", marks=marks), car("c2")))
    timeline = page.one("svg", data_vehicle="c1")
    assert timeline.attrs["role"] == "img"
    assert "c1" in timeline.attrs["aria-label"]
    assert "c1" in timeline.children[0].text() and timeline.children[0].tag == "title"
    rollback = timeline.one(data_kind="rollback")
    assert "g2 failed its health check" in rollback.one("title").text()
    assert "2026-10-26 08:24 UTC" in rollback.one("title").text()  # when, in words
    assert "gate moving" in timeline.one(data_kind="deferral").one("title").text()
    assert len(timeline.all(data_kind="ran")) == 2
    assert not page.one("svg", data_vehicle="c2").all(data_kind="rollback")


def test_narrow_runs_merge_but_every_rollback_stays() -> None:
    """A month is 1000 units: 200 one-minute runs in an hour are one bar; 50 rollbacks in
    the same hour are 50 markers."""
    runs = tuple(Mark(at(2) + timedelta(minutes=n), at(2) + timedelta(minutes=n + 1), "ran",
                      f"alpha@g{n}") for n in range(200))
    rollbacks = tuple(Mark(at(2) + timedelta(minutes=n), at(2) + timedelta(minutes=n),
                           "rollback", f"reason {n}") for n in range(50))
    deferrals = tuple(Mark(at(9), at(9), "deferral", f"gate {n}") for n in range(30))
    page = tree(view(car("c1", marks=runs + rollbacks + deferrals)))
    timeline = page.one("svg", data_vehicle="c1")
    bars = timeline.all(data_kind="ran")
    assert len(bars) < 10
    assert "200 short runs" in "".join(b.text() for b in bars)
    assert len(timeline.all(data_kind="rollback")) == 50
    deferred = timeline.one(data_kind="deferral")
    assert "30 deferrals" in deferred.text() and "and 25 more" in deferred.text()


def test_two_apps_flapping_together_still_merge() -> None:
    """Marks come oldest first: two apps' narrow runs interleave, each lane merges its own."""
    runs = tuple(Mark(at(2) + timedelta(minutes=n), at(2) + timedelta(minutes=n + 1), "ran",
                      f"{'ab'[n % 2]}@g{n}") for n in range(400))
    timeline = tree(view(car("c1", marks=runs))).one("svg", data_vehicle="c1")
    bars = timeline.all(data_kind="ran")
    assert len(bars) == 2
    assert {b.attrs["y"] for b in bars} == {"28", "46"}  # a lane each


def test_the_age_of_each_report() -> None:
    page = tree(view(car("c1"), car("c2", reported=None),
                     car("c3", reported=NOW - timedelta(days=3))))
    assert row(page, "c1").all("td")[-1].text() == "12 min ago"
    assert row(page, "c2").all("td")[-1].text() == "never"
    assert row(page, "c3").all("td")[-1].text() == "3 d ago"
    assert ago(-7200) == "2 h ahead (the car's clock)"


def test_the_header_and_that_the_page_stands_alone() -> None:
    page = render(view(car("c1"), rollout="wave 2 of 3: 20% of the fleet"))
    document = Tree(page).root
    header = document.one("header").text()
    assert TIP[:12] in header and TIP[:13] not in header
    assert "2026-11-20T06:00:00Z" in header
    assert "wave 2 of 3: 20% of the fleet" in header
    assert document.one("meta", name="viewport").attrs["content"] == \
        "width=device-width, initial-scale=1"
    assert page.startswith("<!DOCTYPE html>")
    # nothing fetched: no script, no source, no link, no url() in the CSS
    assert not re.search(r"<script|<link|<img|<iframe|src=|url\(|@import", page, re.I)
    assert re.findall(r"https?://[^\"' ]+", page) == ["http://www.w3.org/2000/svg"]
    assert "overflow-x:auto" in page
    assert "Rollout" not in render(view(car("c1")))  # no rollout declared: no line
