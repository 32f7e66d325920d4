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
from schemas.record import (
    AppRecord,
    AppStatus,
    HistoryEntry,
    Hold,
    RepositoryRecord,
    StateRecord,
)
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


@pytest.mark.parametrize("scripts", [True, False])
def test_a_step_is_under_way_while_its_apply_lives_and_cut_off_once_it_is_gone(
        scripts: bool) -> None:
    """Item 2, on the app's row: while the apply lives (the last apply's line says "in
    progress"), its start is under way, never "cut off"; once its process is gone, it was
    cut off. An app lpam runs as a unit of its own has no start.sh to name."""
    app = AppRecord(name="alpha", repository="apps", commit=COMMIT, tree="t" * 40,
                    path="alpha/", generation="alp-g1", status="starting",
                    command=None if scripts else ["python3", "run.py"])
    record = StateRecord(apps=[app])
    for alive, says, never in ((True, "under way", "did not finish"),
                               (False, "did not finish", "under way")):
        report = build(Seen(record=record, alive=alive))
        text = report.installed[0].said
        assert says in text and never not in text, text
        assert ("start.sh" in text) is scripts, text


@pytest.mark.parametrize("mode", ["0", "1"])
def test_a_rollback_that_did_not_reach_its_set_is_owed_not_done(mode: str) -> None:
    """A rollback whose stop.sh failed left the app with the parameters it rolled back
    from; plan then finishes the rollback. Status must not say it "returned": the hold and
    the app's row say what the next apply still does."""
    app = AppRecord(name="alpha", repository="apps", commit=COMMIT, tree="t" * 40,
                    path="alpha/", generation="alp-g1", status="running", params={"M": "1"})
    back = HistoryEntry(generation="alp-g1", app="alpha", repository="apps", commit=COMMIT,
                        path="alpha/", tree="t" * 40, params={"M": mode}, time="T",
                        result="applied")
    report = build(Seen(record=StateRecord(apps=[app], hold=Hold(desired="f" * 64,
                                                                 targets=[back]))))
    done = mode == "1"  # the app is what the rollback returns to
    hold = report.holds[0].what
    assert ("returned to generation" in hold) is done, hold
    assert ("did not finish" in hold) is not done, hold
    said = report.installed[0].said
    assert ("the next apply finishes it" in said) is not done, said
    assert "held by `lpam rollback`" in said


def test_a_stop_that_did_not_finish_on_an_unknown_unit_is_marked_unverified() -> None:
    """Found by the consistency property: `lpam stop` killed before its first step left
    an app held while its record says running and no manager knows its unit; the row
    showed Running yes and nowhere that this is only lpam's record."""
    report = car("running", UNKNOWN, held=True)
    [app] = report.installed
    assert app.running and not app.verified
    assert app.standing == "stopping" and "unverified" in app.said, app.said
