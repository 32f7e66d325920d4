"""Each installed app's status is one word of a closed set (schemas/report.py `Standing`),
derived with whether it runs (issue 30, item 6): the table's Status and Running columns,
the app's line under the table and the JSON cannot disagree, an app whose unit its manager
cannot know says `unverified`, and a stopped app is never said to run. Built from values
alone, as the report is pure."""

from __future__ import annotations

from typing import get_args

import pytest

from reconciler.base.unit import UnitState
from reconciler.report import table
from reconciler.report.build import build
from reconciler.report.gather import Listing, Seen
from reconciler.report.status import json_of
from schemas.catalog import CatalogApp
from schemas.record import AppRecord, AppStatus, Hold, RepositoryRecord, StateRecord
from schemas.report import Standing, StatusReport

COMMIT = "c" * 40


def car(status: AppStatus, unit: UnitState | None, *, held: bool = False,
        hold: bool = False) -> StatusReport:
    """One app, `alpha`, recorded `status`, its unit as its manager answers (`unit`)."""
    app = AppRecord(name="alpha", repository="apps", commit=COMMIT, tree="t" * 40,
                    path="alpha/", generation="alp-g1", status=status,
                    service=None if unit is None else unit.name, held=held)
    record = StateRecord(
        repositories=[RepositoryRecord(key="apps", url="git://x/apps.git", ref="main",
                                       commit=COMMIT, applied=COMMIT)],
        apps=[app], hold=Hold(desired="f" * 64, targets=[]) if hold else None)
    listing = Listing("apps", "main", COMMIT[:12], (CatalogApp(name="alpha", path="alpha/"),))
    return build(Seen(record=record, listings=(listing,),
                      lives={} if unit is None else {"alpha": unit}, manager="supervisor"))


def row(report: StatusReport) -> dict[str, str]:
    """The table's row of `alpha`, by column."""
    lines = table.render(report).splitlines()
    header = lines[0]
    starts = [header.index(c.capitalize()) for c in table.COLUMNS]
    line = next(x for x in lines[1:] if x.startswith("apps "))
    ends = [*starts[1:], None]
    return {c: line[a:b].strip() for c, a, b in zip(table.COLUMNS, starts, ends)}


ACTIVE = UnitState("lpam-app-alpha", True, "active", "RUNNING", pid=42)
INACTIVE = UnitState("lpam-app-alpha", True, "inactive", "STOPPED")
UNKNOWN = UnitState("can", False)


@pytest.mark.parametrize(("status", "unit", "held", "word", "runs"), [
    ("running", ACTIVE, False, "running", "yes"),
    # `lpam services shutdown`: the manager is gone, so is the app: never "running"
    ("running", INACTIVE, False, "not running", "no"),
    ("installed", INACTIVE, True, "stopped by operator", "no"),
    ("running", ACTIVE, True, "stopping", "yes"),
    ("starting", INACTIVE, False, "starting", "no"),
    ("installed", INACTIVE, False, "installed", "no"),
    # a unit its manager cannot know (a script app's own `service` on supervisord)
    ("running", UNKNOWN, False, "unverified", "yes"),
])
def test_the_status_word_and_running_come_from_one_answer(
        status: AppStatus, unit: UnitState, held: bool, word: Standing, runs: str) -> None:
    report = car(status, unit, held=held)
    [app] = report.installed
    assert app.standing == word and word in get_args(Standing)
    shown = row(report)
    assert shown["running"] == runs
    assert shown["status"].split(" (")[0].split(":")[0].split(";")[0] == word, shown
    assert json_of(report)["installed"][0]["standing"] == word
    if runs == "no":
        assert not shown["status"].startswith("running"), shown


def test_a_drifted_app_is_not_running_beside_running_no() -> None:
    """After `lpam services shutdown`: Running `no`, and the status says so and what the
    next apply does, never `running`."""
    shown = row(car("running", INACTIVE))
    assert (shown["running"], shown["status"]) == (
        "no", "not running (drift: the next apply starts it)")


def test_an_app_whose_unit_is_unknown_says_unverified() -> None:
    report = car("running", UNKNOWN)
    assert row(report)["status"] == "unverified: recorded running"
    assert json_of(report)["installed"][0]["verified"] is False
    assert "unverified" in table.render(report)


def test_a_stopped_app_is_not_said_to_have_reported_running() -> None:
    """A script app stopped by its operator, its unit unknown to the manager: nothing
    says its scripts reported it running."""
    report = car("installed", UNKNOWN, held=True)
    text = table.render(report)
    assert "stopped by operator" in text
    assert "running is what" not in text and "reported" not in text, text
    assert row(report)["running"] == "no"


def test_under_a_rollback_hold_no_status_promises_the_next_apply() -> None:
    """Plans propose nothing while a rollback holds: the status says the hold instead."""
    report = car("running", INACTIVE, hold=True)
    [app] = report.installed
    assert app.rollback_hold and "next apply" not in app.said
    assert app.said == "not running (held by `lpam rollback`)"
