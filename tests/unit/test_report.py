"""One status report, five faces: `lpam status`'s table, `lpam status --json`,
`libpanda-app-manager -d/-c/-t`, the phone's `A` and summary, and the status a car
publishes all render the one value reconciler/report/build.py makes, so none can say of an
app what another does not. Built here from values alone (no store, no manager, no files):
the report is pure, and each face is checked against it, then against a changed one."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

import pytest

from reconciler.base.layout import Layout
from reconciler.base.unit import UnitState
from reconciler.core.planning.plan import seal
from reconciler.core.privzone.messages import app_info_message
from reconciler.core.publication import read_status_file, status_file
from reconciler.engine.records.state import write_record
from reconciler.frontends.ble.answers import summary_of
from reconciler.frontends.shim import lpam_text
from reconciler.report import table
from reconciler.report.build import build
from reconciler.report.gather import Listing, Seen
from reconciler.report.status import json_of, report
from schemas.agent import AgentStatus
from schemas.catalog import CatalogApp
from schemas.plan import Action, Change
from schemas.record import AppRecord, AppStatus, LastApply, RepositoryRecord, StateRecord
from schemas.report import StatusReport

COMMIT = "c" * 40
NAMES = ("controller", "recorder", "tracker")
WHERE = Path("status/rav4-07/status.json")
AGENT = AgentStatus(vehicle="rav4-07", follows="desired-state.yaml",
                    applied_revision="d" * 40)


def app(name: str, status: AppStatus = "running", *, held: bool = False) -> AppRecord:
    return AppRecord(name=name, repository="apps", commit=COMMIT, tree="t" * 40,
                     path=f"{name}/", generation=f"{name[:3]}-g1", status=status,
                     service=f"lpam-app-{name}", command=["python3", f"{name}.py"],
                     resources=["panda"] if name == "controller" else [], held=held)


def seen(stopped: frozenset[str] = frozenset({"recorder"}),
         drifted: frozenset[str] = frozenset()) -> Seen:
    """Three apps installed from one repository, which also lists an app not installed;
    the apps in `stopped` were stopped by `lpam stop` (held, their units inactive), those
    in `drifted` are recorded running but their units are inactive (the manager's word
    counts)."""
    record = StateRecord(
        repositories=[RepositoryRecord(key="apps", url="git://x/apps.git", ref="main",
                                       commit=COMMIT, applied=COMMIT)],
        apps=[app(n, "installed" if n in stopped else "running", held=n in stopped)
              for n in NAMES],
        last_apply=LastApply(time="2026-11-27T10:00:00+00:00", result="applied"))
    units = {n: UnitState(f"lpam-app-{n}", True, "inactive") if n in stopped | drifted else
             UnitState(f"lpam-app-{n}", True, "active", "RUNNING", pid=100)
             for n in NAMES}
    listed = tuple(CatalogApp(name=n, path=f"{n}/", description=f"the {n}")
                   for n in (*NAMES, "spare"))
    return Seen(record=record, listings=(Listing("apps", "main", COMMIT[:12], listed),),
                lives=units, manager="supervisord", agent=AGENT)


def faces(report: StatusReport) -> dict[str, dict[str, tuple[bool, bool]]]:
    """Each face's word on each app: (installed or enabled, running), by app name."""
    out: dict[str, dict[str, tuple[bool, bool]]] = {}
    yes = {"yes": True, "no": False}
    body = json_of(report)
    installed = {a["name"] for a in body["installed"]}
    out["json"] = {a["name"]: (a["name"] in installed, a["running"]) for a in body["installed"]}
    out["json rows"] = {r["app"]: (r["installed"], r["running"]) for r in body["apps"]}
    lines = table.render(report).splitlines()[1:]  # under the header
    cells = [line.split() for line in lines if line.startswith("apps ")]
    out["table"] = {c[3]: (yes[c[5]], yes[c[6]]) for c in cells}
    d = [line.split("\t") for line in lpam_text("d", report).splitlines()[1:]]
    out["shim -d"] = {c[2]: (yes[c[4]], yes[c[5]]) for c in d}
    message = json.loads(b"".join(app_info_message(report.listed()))[:-1])
    rows = json.loads(message["contents"])
    out["phone A"] = {r["app"]: (yes[r["enabled"]], yes[r["running"]]) for r in rows}
    read = read_status_file(status_file(AGENT, [a.published() for a in report.installed]),
                            where=WHERE)
    assert read is not None
    out["published"] = {a.name or "": (True, bool(a.running)) for a in read.installed()}
    return out


def truth(report: StatusReport) -> dict[str, tuple[bool, bool]]:
    """The report's own word: installed apps, and every listed app."""
    return {r.app: (r.installed, r.running) for r in report.listed()}


def test_every_face_says_what_the_one_report_says() -> None:
    report = build(seen(drifted=frozenset({"controller"})))
    assert truth(report) == {"controller": (True, False), "recorder": (True, False),
                             "tracker": (True, True), "spare": (False, False)}
    for face, said in faces(report).items():
        expected = truth(report) if face not in ("json", "published") else \
            {n: v for n, v in truth(report).items() if v[0]}
        assert said == expected, face
    # the words beside the flags: the lifecycle said, the holds, the installed names
    text = table.render(report)
    held = next(a for a in report.installed if a.name == "recorder")
    assert held.said == "stopped by operator" and held.said in text
    assert [h.what for h in report.holds] == [
        "recorder was stopped by `lpam stop` and stays stopped"]
    assert report.holds[0].what in text
    assert lpam_text("c", report).split() == list(NAMES)
    assert lpam_text("t", report).splitlines() == [f"{a.name}: {a.unit.said}"
                                                   for a in report.installed
                                                   if a.unit is not None]
    summary = summary_of(report)
    assert (summary["app"], summary["running"], summary["status"]) == (
        "controller", "no", "not running")  # one word with `running`, never "running"
    assert summary["apps"] == \
        "controller not running, recorder stopped by operator, tracker running"
    assert summary["applied_revision"] == "d" * 40
    assert json_of(report)["app"]["name"] == summary["app"]


def test_a_changed_car_changes_every_face_at_once() -> None:
    """No face keeps an answer of its own: start the recorder and stop the tracker, and
    all five say so."""
    before = build(seen())
    after = build(seen(frozenset({"tracker"})))
    assert truth(after)["recorder"] == (True, True) and truth(after)["tracker"] == (True, False)
    for face, said in faces(after).items():
        assert said["recorder"] == (True, True), face
        assert said["tracker"] == (True, False), face
        assert said != faces(before)[face], face
    assert "tracker" in table.render(after) and "stopped by operator" in next(
        a.said for a in after.installed if a.name == "tracker")


def test_the_report_is_a_versioned_document() -> None:
    body = json_of(build(seen()))
    assert body["version"] == 1
    assert StatusReport.model_validate({k: v for k, v in body.items() if k != "app"}) == \
        build(seen())


def test_the_phone_summary_says_the_plan_the_report_holds() -> None:
    """The plan an apply would run now goes into the report whole (each change and why);
    the phone's summary renders its summary, and a plan that could not be made says why."""
    change = Change(address="app.recorder", action=Action.UPDATE,
                    reason="recorder is not running: start")
    plan = seal(StateRecord(), [change], [], now=datetime(2026, 11, 27, tzinfo=timezone.utc),
                lpam_version="t")
    report = build(seen(), plan=plan, gates="speed: open (stationary)")
    assert report.plan is not None and report.plan.changes == [change]
    assert summary_of(report)["plan"] == plan.summary != ""
    assert summary_of(report)["gates"] == "speed: open (stationary)"
    assert json_of(report)["plan"]["changes"][0]["reason"] == change.reason
    unknown = build(seen(), plan="not known: the lock is held")
    assert summary_of(unknown)["plan"] == "not known: the lock is held"
    assert summary_of(build(seen()))["plan"] == ""  # status itself plans nothing


class Untouchable:
    """A repository store that fails any read: what must not be read reads nothing."""

    def has_commit(self, key: str, commit: str) -> bool:
        raise AssertionError("read the store")

    def read_file(self, key: str, commit: str, path: str) -> bytes | None:
        raise AssertionError("read the store")

    def damage(self, key: str) -> str | None:
        raise AssertionError("read the store")

    def location(self, key: str) -> Path:
        raise AssertionError("read the store")


def test_the_installed_apps_alone_read_no_catalog(tmp_path: Path) -> None:
    """The published status and the phone's summary show the installed apps: their report
    reads no repository (an agent publishes every few minutes), and says the same of
    each installed app as the whole one."""
    layout = Layout(tmp_path / "root")
    write_record(layout, seen().record)
    units = seen().lives
    short = report(layout, store=Untouchable(), state=lambda unit: units[unit[9:]],
                   listed=False)
    assert short.apps == [] and short.installed == build(seen()).installed
    with pytest.raises(AssertionError, match="read the store"):
        report(layout, store=Untouchable(), state=lambda unit: units[unit[9:]])
