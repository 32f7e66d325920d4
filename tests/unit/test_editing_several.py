"""The field's app switch with several apps (issue 22, item 5): the phone's `app_enable X`
and `libpanda-app-manager -i X` (workflow/editing.py `enable_app`) in a version-2 desired
state replace only the apps that claim a resource X claims, leave the others as written
(entries, params, comments), add an X that claims nothing, and change nothing for an X
already listed. The claims come from the catalogs in the store, read with no network; a
catalog that cannot be read there falls back to replacing the whole list. A version-1
file keeps its one app's behaviour exactly.

The text an edit would write is caught where it is handed to the apply (the apply itself
is the shim's and the phone's integration tests'); the store is the in-memory twin, whose
network calls fail the test.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from reconciler.adapters.memory import MemoryStore
from reconciler.base.layout import Layout
from reconciler.engine.execution.ports import RemoteRefs
from reconciler.workflow import editing
from reconciler.workflow.applying import Applied, ApplyOptions
from reconciler.workflow.events import Event, Note
from reconciler.workflow.machine import Machine
from schemas.desired import DesiredState

URL = "https://github.com/fleet/apps"
KEY = "fleet/apps"
COMMIT = "c" * 40
CATALOG = """\
apps:
  - name: controller
    properties:
      - owns_panda: true
  - name: controller2
    properties:
      - owns_panda: true
  - name: recorder
  - name: tracker
    resources: [gps-serial]
  - name: logger
  - name: navigator
    properties:
      - owns_panda: true
    resources: [gps-serial]
"""
APPS = ("controller", "controller2", "recorder", "tracker", "logger", "navigator")

V2 = f"""\
# the car's apps: a controller beside its loggers
version: 2
repositories:
  - url: {URL}
    ref: main   # follow the branch
apps:
  - name: controller      # drives the car (a comment at its own column)
    params: {{GAIN: "2"}}
  # the bag writer, on every drive
  - name: recorder
    params: {{TOPICS: "/vel /acc"}}  # what it records
  - name: tracker  # the GPS
# end of file
"""
V1 = f"""\
# one app, as LPAM had it
version: 1
repositories:
  - url: {URL}
    ref: main
app:
  name: controller    # drives the car
  params: {{GAIN: "2"}}
# end of file
"""


def offline_store() -> MemoryStore:
    """The app repository as the last fetch left it; any network call fails the test."""
    tree = {"": ("t0", {"libpanda-apps.yaml": CATALOG})}
    tree.update({name: (f"t-{name}", {"start.sh": "true\n"}) for name in APPS})
    store = MemoryStore(remotes={URL: {COMMIT: tree}})
    store.advertised[URL] = RemoteRefs(url=URL, refs={"refs/heads/main": COMMIT},
                                       default_branch="main")
    store.fetch(KEY, URL)

    def network(*args: object) -> None:
        raise AssertionError("the switch went to the network")

    store.fetch = store.fetch_objects = store.ls_remote = network  # type: ignore[method-assign,assignment]
    return store


@pytest.fixture
def caught(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """The text and desired state each edit hands to the apply."""
    found: dict[str, Any] = {}

    def fake(machine: Machine, found_: Any, text: str, desired: DesiredState,
             **_: Any) -> editing.Edited:
        found.update(text=text, desired=desired)
        return editing.Edited(text != found_.text, Applied(0, "-"))

    monkeypatch.setattr(editing, "_apply", fake)
    return found


def car(tmp_path: Path, text: str, store: MemoryStore | None) -> Machine:
    machine = Machine.at(Layout(tmp_path / "root"))
    machine.layout.desired_state.parent.mkdir(parents=True)
    machine.layout.desired_state.write_text(text)
    if store is not None:
        machine.store = lambda: store  # type: ignore[method-assign,assignment,return-value]
    return machine


def switch(machine: Machine, name: str | None, notes: list[str] | None = None) -> bool:
    def report(event: Event) -> None:
        if isinstance(event, Note) and notes is not None:
            notes.append(event.text)

    done = editing.enable_app(machine, name, by="t", options=ApplyOptions(), report=report)
    return done.changed


def test_a_new_panda_owner_replaces_the_controller_only(tmp_path: Path,
                                                       caught: dict[str, Any]) -> None:
    machine = car(tmp_path, V2, offline_store())
    assert switch(machine, "controller2")
    assert caught["text"] == V2.replace(
        '  - name: controller      # drives the car (a comment at its own column)\n'
        '    params: {GAIN: "2"}\n',
        "  - name: controller2     # drives the car (a comment at its own column)\n")
    assert [(a.name, a.params) for a in caught["desired"].apps] == [
        ("controller2", {}), ("recorder", {"TOPICS": "/vel /acc"}), ("tracker", {})]


def test_an_app_that_claims_nothing_is_added_beside_the_others(
        tmp_path: Path, caught: dict[str, Any]) -> None:
    machine = car(tmp_path, V2, offline_store())
    assert switch(machine, "logger")
    assert caught["text"] == V2.replace("  - name: tracker  # the GPS\n",
                                        "  - name: tracker  # the GPS\n  - name: logger\n")
    assert [a.name for a in caught["desired"].apps] == \
        ["controller", "recorder", "tracker", "logger"]


def test_an_app_claiming_two_resources_replaces_both_owners(
        tmp_path: Path, caught: dict[str, Any]) -> None:
    machine = car(tmp_path, V2, offline_store())
    assert switch(machine, "navigator")
    assert caught["text"] == V2.replace(
        '  - name: controller      # drives the car (a comment at its own column)\n'
        '    params: {GAIN: "2"}\n',
        "  - name: navigator       # drives the car (a comment at its own column)\n"
    ).replace("  - name: tracker  # the GPS\n", "")
    assert [a.name for a in caught["desired"].apps] == ["navigator", "recorder"]


def test_an_app_already_listed_changes_nothing(tmp_path: Path, caught: dict[str, Any]
                                               ) -> None:
    machine = car(tmp_path, V2, offline_store())
    assert not switch(machine, "recorder")
    assert caught["text"] == V2


def test_a_flow_list_gets_the_name_alone(tmp_path: Path, caught: dict[str, Any]) -> None:
    text = V2.split("\napps:")[0] + "\napps: [controller, recorder]\n"
    machine = car(tmp_path, text, offline_store())
    switch(machine, "logger")
    assert caught["text"] == text.replace("recorder]", "recorder, logger]")
    switch(machine, "controller2")
    assert caught["text"] == text.replace("[controller,", "[controller2,")


def test_no_app_stops_every_app(tmp_path: Path, caught: dict[str, Any]) -> None:
    machine = car(tmp_path, V2, offline_store())
    assert switch(machine, None)
    assert "apps: []\n" in caught["text"] and caught["desired"].apps == []
    assert caught["text"].startswith("# the car's apps") and "# follow the branch" in \
        caught["text"]


def test_a_catalog_not_readable_offline_replaces_the_whole_list(
        tmp_path: Path, caught: dict[str, Any]) -> None:
    """A repository never fetched: the claims are not known here, so the switch is what it
    was before several apps (the apply then fetches and plans it), and a note says why."""
    machine = car(tmp_path, V2, MemoryStore())
    notes: list[str] = []
    switch(machine, "logger", notes)
    assert [a.name for a in caught["desired"].apps] == ["logger"]
    assert caught["text"] == V2.split("\napps:")[0] + "\napps:\n  - name: logger\n# end of file\n"
    assert len(notes) == 1 and "logger replaces every listed app" in notes[0]
    assert "not fetched yet" in notes[0]


def test_a_version_1_file_keeps_its_one_app(tmp_path: Path, caught: dict[str, Any]) -> None:
    """Even an app that claims nothing replaces the one app of a version-1 file: that
    format holds one app, and an edit never changes a file's version."""
    machine = car(tmp_path, V1, offline_store())
    switch(machine, "logger")
    assert caught["text"] == V1.replace(
        '  name: controller    # drives the car\n  params: {GAIN: "2"}\n',
        "  name: logger        # drives the car\n")
    switch(machine, None)
    assert caught["text"] == V1.split("app:")[0] + "app: null\n# end of file\n"


def test_no_installed_app_loses_its_repository(tmp_path: Path, caught: dict[str, Any]) -> None:
    """`-r` / `app_remove_repository` is refused for the repository of any installed app,
    not only the first one installed."""
    from reconciler.base.errors import LpamError
    from reconciler.engine.records.state import write_record
    from schemas.record import AppRecord, StateRecord

    tools = "https://github.com/extra/tools"
    text = V2.replace("apps:\n", f"  - url: {tools}\napps:\n", 1)
    machine = car(tmp_path, text, offline_store())
    installed = [AppRecord(name=name, generation=f"g-{name}", repository=key, commit=COMMIT,
                           tree=f"t-{name}", path=name, status="running")
                 for name, key in (("controller", KEY), ("gadget", "extra/tools"))]
    write_record(machine.layout, StateRecord(apps=installed))
    with pytest.raises(LpamError, match="installed app gadget comes from extra/tools"):
        editing.remove_repository(machine, "extra/tools", by="t", options=ApplyOptions(),
                                  report=lambda event: None)
    assert caught == {}  # nothing was handed to an apply
