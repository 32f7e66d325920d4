"""Every face shows every installed app (issue 22, item 5), against an in-memory record of a
car running three apps at once: a controller that owns the panda, a recorder and a tracker
that claim nothing exclusive.

What a user checks: `lpam status` and `--json` list the three with their state, generation,
claims and unit (the `app` key still the first, for readers from before several apps); an
operator's `stop recorder` plans the recorder's stop and nothing of the others; `start`
with no name starts every stopped app and leaves the running ones alone; a car running the
three publishes all three and `lpam fleet status` shows them, while a car with one app
publishes exactly the file it published before.
"""

from __future__ import annotations

import argparse
import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pytest

from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.errors import LpamError
from reconciler.base.layout import Layout
from reconciler.base.unit import UnitState
from reconciler.core.planning.ensemble import operator_steps
from reconciler.core.planning.model import GenerationKey
from reconciler.core.publication import (
    essentials,
    fingerprint,
    read_status_file,
    status_file,
)
from reconciler.engine.records.state import write_record
from reconciler.frontends.cli import again
from reconciler.report import status
from reconciler.workflow import fleet
from reconciler.workflow.logs import app_logs, new_output
from reconciler.workflow.machine import Machine
from reconciler.workflow.operate import chosen_apps
from schemas.agent import AgentStatus
from schemas.fleet import PublishedApp
from schemas.generation import AppGeneration
from schemas.operator import OperatorAction
from schemas.plan import Step
from schemas.record import AppRecord, AppStatus, RepositoryRecord, StateRecord
from tests.unit.test_status import Blobs

COMMIT = "c" * 40
CATALOG = (b"apps:\n  - name: controller\n    properties:\n      - owns_panda: true\n"
           b"  - name: recorder\n  - name: tracker\n")
CLAIMS = {"controller": ["panda"], "recorder": [], "tracker": []}
GENERATIONS = frozenset(GenerationKey.of(name, f"{name[:3]}-g1") for name in CLAIMS)


def installed(name: str, state: AppStatus = "running", *, held: bool = False) -> AppRecord:
    return AppRecord(name=name, repository="apps", commit=COMMIT, tree="t" * 40,
                     path=f"{name}/", generation=f"{name[:3]}-g1", status=state,
                     service=f"lpam-app-{name}", command=["python3", f"{name}.py"],
                     resources=CLAIMS[name], held=held)


def car(recorder: AppStatus = "running", *, held: bool = False) -> StateRecord:
    """The three apps, in the order they were installed; the recorder as asked."""
    return StateRecord(
        repositories=[RepositoryRecord(key="apps", url="git://x/apps.git", ref=None,
                                       commit=COMMIT, applied=COMMIT)],
        apps=[installed("controller"), installed("recorder", recorder, held=held),
              installed("tracker")])


def store() -> Blobs:
    files: dict[tuple[str, str, str], bytes | Exception] = {
        ("apps", COMMIT, "libpanda-apps.yaml"): CATALOG}
    files.update({("apps", COMMIT, f"{n}/description.txt"): f"the {n}\n".encode()
                  for n in CLAIMS})
    return Blobs(files)


def manager(stopped: frozenset[str] = frozenset()) -> dict[str, UnitState]:
    """Each app's unit as supervisord would report it: running, but for `stopped`."""
    return {f"lpam-app-{n}": UnitState(f"lpam-app-{n}", True, "inactive") if n in stopped
            else UnitState(f"lpam-app-{n}", True, "active", "RUNNING", pid=100 + i)
            for i, n in enumerate(CLAIMS)}


def recorder_stopped(layout: Layout) -> dict[str, Any]:
    """The car after `lpam stop recorder`: recorded held, its unit inactive; what status
    is asked with (the store, the manager)."""
    write_record(layout, car("installed", held=True))
    units = manager(stopped=frozenset({"recorder"}))
    return {"store": store(), "state": units.__getitem__, "manager": "supervisord"}


@pytest.fixture
def layout(tmp_path: Path) -> Layout:
    return Layout(tmp_path / "root")


def test_status_json_lists_every_installed_app_and_keeps_app_the_first(
    layout: Layout
) -> None:
    shown = status.as_json(layout, **recorder_stopped(layout))
    assert shown["app"]["name"] == "controller" and "claims" not in shown["app"]
    every = {a["name"]: a for a in shown["installed"]}
    assert [a["name"] for a in shown["installed"]] == ["controller", "recorder", "tracker"]
    assert every["controller"]["claims"] == ["panda"]
    assert every["recorder"]["claims"] == every["tracker"]["claims"] == []
    assert {n: a["generation"] for n, a in every.items()} == {
        "controller": "con-g1", "recorder": "rec-g1", "tracker": "tra-g1"}
    recorder = every["recorder"]
    assert (recorder["running"], recorder["held"], recorder["status"]) == (
        False, True, "installed")
    assert recorder["unit"]["active"] == "inactive" and recorder["verified"] is True
    assert every["tracker"]["unit"]["pid"] == 102 and every["tracker"]["running"] is True
    rows = {r["app"]: r for r in shown["apps"]}
    assert all(rows[n]["installed"] for n in CLAIMS)
    assert (rows["recorder"]["running"], rows["tracker"]["running"]) == (False, True)
    assert [h["what"].split()[0] for h in shown["holds"]] == ["recorder"]
    assert "lpam start recorder" in shown["holds"][0]["ends"]


def test_status_table_shows_each_apps_state_generation_claims_and_unit(
    layout: Layout
) -> None:
    lines = status.as_table(layout, **recorder_stopped(layout)).splitlines()
    table = {line.split()[3]: line for line in lines[1:4]}
    assert set(table) == set(CLAIMS)
    assert "running" in table["controller"].split() and "stopped by operator" in \
        table["recorder"]
    assert "Installed apps: 3; service manager: supervisord" in lines
    controller, recorder, tracker = (next(line for line in lines
                                          if line.startswith(f"  {n} (generation"))
                                     for n in CLAIMS)
    assert "con-g1" in controller and "claims panda;" in controller
    assert "unit lpam-app-controller active (RUNNING)" in controller
    assert "claims nothing exclusive" in recorder and "inactive" in recorder
    assert "stopped by operator" in recorder
    assert "tra-g1" in tracker and "claims nothing exclusive" in tracker
    assert any(line.startswith("Held: recorder was stopped") for line in lines)


def test_a_car_with_one_app_shows_no_list_under_the_table(layout: Layout) -> None:
    one = car().model_copy(update={"apps": [installed("controller")]})
    write_record(layout, one)
    lines = status.as_table(layout, store=store(), state=manager().__getitem__,
                            manager="supervisord").splitlines()
    assert not any(line.startswith("Installed apps") for line in lines)
    assert "Service manager: supervisord; unit lpam-app-controller active (RUNNING)" in lines
    assert [a["name"] for a in status.as_json(layout, store=store())["installed"]] == [
        "controller"]


def touched(steps: list[Step]) -> list[tuple[str, str | None]]:
    """(kind, app) of each step, in order (a stray's step names no app)."""
    found = [(s, getattr(s, "app", None)) for s in steps]
    return [(s.kind.value, app.name if isinstance(app, AppGeneration) else None)
            for s, app in found]


def test_stop_of_one_app_plans_its_stop_and_nothing_of_the_others() -> None:
    steps = operator_steps(car(held=True), OperatorAction.STOP, GENERATIONS,
                           names=["recorder"])
    assert touched(steps) == [("stop", "recorder")]


def test_start_without_a_name_starts_every_stopped_app_and_only_those() -> None:
    record = car("installed", held=True).with_app(
        "tracker", installed("tracker", "installed"))
    steps = operator_steps(record, OperatorAction.START, GENERATIONS)
    assert sorted(touched(steps)) == [("start", "recorder"), ("start", "tracker")]


def test_restart_of_one_app_stops_and_starts_it_alone() -> None:
    steps = operator_steps(car(), OperatorAction.RESTART, GENERATIONS, names=["tracker"])
    assert touched(steps) == [("stop", "tracker"), ("start", "tracker")]


def test_stop_without_a_name_stops_all_three() -> None:
    steps = operator_steps(car(), OperatorAction.STOP, GENERATIONS)
    assert sorted(touched(steps)) == [("stop", n) for n in sorted(CLAIMS)]


def test_an_unknown_app_is_refused_naming_the_installed_ones() -> None:
    with pytest.raises(LpamError) as refused:
        chosen_apps(car(), "recordr", OperatorAction.STOP)
    assert "recordr" in refused.value.message
    assert refused.value.hint == "installed: controller, recorder, tracker"
    assert [a.name for a in chosen_apps(car(), None, OperatorAction.START)] == list(CLAIMS)


AGENT = AgentStatus(vehicle="rav4-07", follows="desired-state.yaml",
                    applied_revision="d" * 40)
WHERE = Path("status/rav4-07/status.json")


def published(record: StateRecord, stopped: frozenset[str] = frozenset()
              ) -> list[PublishedApp]:
    """What sync.publish hands publication: each app as the status report has it."""
    return [PublishedApp(name=a.name, generation=a.generation, status=a.status,
                         running=a.name not in stopped) for a in record.apps]


def test_a_car_running_three_apps_publishes_them_and_the_fleet_sees_them() -> None:
    apps = published(car("installed"), frozenset({"recorder"}))
    content = status_file(AGENT, apps)
    body = json.loads(content)
    assert body["version"] == 3 and body["app"]["name"] == "controller"
    assert [a["name"] for a in body["apps"]] == ["controller", "recorder", "tracker"]
    read = read_status_file(content, where=WHERE)
    assert read is not None and [a.running for a in read.installed()] == [True, False, True]
    row = fleet._row("rav4-07", read, "d" * 40, datetime(2026, 11, 25, tzinfo=timezone.utc))
    [shown] = fleet.as_json("d" * 40, [row], now=datetime(2026, 11, 25,
                                                          tzinfo=timezone.utc))["vehicles"]
    assert [a["name"] for a in shown["apps"]] == ["controller", "recorder", "tracker"]
    table = fleet.as_table("d" * 40, [row], now=datetime(2026, 11, 25, tzinfo=timezone.utc))
    assert "controller, recorder, tracker" in table and "yes, no, yes" in table
    # the recorder starting again is news to the fleet
    again = published(car())
    assert fingerprint(AGENT, again) != fingerprint(AGENT, apps)


def test_a_car_with_one_app_publishes_the_file_it_published_before() -> None:
    [app] = published(car().model_copy(update={"apps": [installed("controller")]}))
    assert set(json.loads(status_file(AGENT, [app]))) == {"version", "agent", "app",
                                                            "override", "last_change"}
    assert "apps" not in essentials(AGENT, [app])  # so its fingerprint is what it was
    read = read_status_file(status_file(AGENT, [app]), where=WHERE)
    assert read is not None and [a.name for a in read.installed()] == ["controller"]


def logged_car(layout: Layout) -> tuple[Machine, MemoryServices]:
    """The three apps installed, each unit known to its manager, each having printed two
    lines."""
    write_record(layout, car())
    services = MemoryServices(known_units={f"lpam-app-{n}" for n in CLAIMS},
                              output={f"lpam-app-{n}": [f"{n} up", f"{n} tick"]
                                      for n in CLAIMS})
    return Machine(layout, given_services=services), services


def test_logs_of_one_app_show_its_output_alone(layout: Layout) -> None:
    machine, _ = logged_car(layout)
    shown = app_logs(machine, 5, "tracker")
    assert (shown.lines, shown.unit) == (["tracker up", "tracker tick"], "lpam-app-tracker")
    with pytest.raises(LpamError) as refused:
        app_logs(machine, 5, "recordr")
    assert refused.value.hint == "installed: controller, recorder, tracker"


def test_logs_without_a_name_show_every_app_each_line_under_its_name(layout: Layout) -> None:
    machine, services = logged_car(layout)
    assert app_logs(machine, 1).lines == [
        "controller | controller tick", "recorder | recorder tick", "tracker | tracker tick"]
    shown = app_logs(machine, 2)
    assert shown.notes == [] and len(shown.lines) == 6
    services.output["lpam-app-recorder"].append("recorder wrote a bag")
    follow = new_output(machine, shown, sleep=lambda s: None)
    assert next(follow) == "recorder | recorder wrote a bag"


def test_a_stop_cut_off_goes_on_with_the_app_it_named() -> None:
    stop = argparse.Namespace(command="stop", app="recorder", root=None, file=None)
    assert again(stop) == "lpam stop recorder"
    assert again(argparse.Namespace(command="start", app=None, root=None, file=None)) == \
        "lpam start"
