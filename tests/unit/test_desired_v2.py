"""Desired state version 2 (`apps:`), and version 1 (`app:`) still read, placed and kept.

Issue 22's first step: a version-1 file reads as version 2 through a pure migration, its
faults are reported at its own lines, lpam's edits keep it version 1 on disk, and a
desired state of several apps is valid yet refused at plan time (no planner for several
apps yet), before the lock and before anything on the machine changes.
"""

from __future__ import annotations

import copy
import hashlib
import re
from pathlib import Path
from typing import Any

import pytest

from migrations import desired_state_v1_to_v2, upgrade
from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.base.loading import load
from reconciler.core.documents import load_desired
from reconciler.workflow import editing
from reconciler.workflow.applying import Applied, ApplyOptions
from reconciler.workflow.events import Event
from reconciler.workflow.machine import Machine
from reconciler.workflow.validation import validate
from schemas.desired import CURRENT_VERSION, DesiredState
from schemas.export import DOCUMENTS, FOLDER, FROZEN

PAIRS_DIR = Path(__file__).resolve().parents[2] / "migrations/fixtures/desired-state/v1_to_v2"
PAIRS = [(b, b.with_name(b.name.replace(".before.", ".after.")))
         for b in sorted(PAIRS_DIR.glob("*.before.yaml"))]


def write(tmp_path: Path, text: str, name: str = "desired.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def quiet(event: Event) -> None:
    pass


@pytest.mark.parametrize(("before", "after"), PAIRS, ids=lambda p: p.name)
def test_v1_to_v2_matches_its_fixture_and_validates(before: Path, after: Path) -> None:
    data = load(before).data
    original = copy.deepcopy(data)
    assert desired_state_v1_to_v2.upgrade(data) == load(after).data
    assert data == original, "a step must not modify its input"
    state = DesiredState.model_validate(upgrade("desired-state", data, path=before))
    assert state.version == CURRENT_VERSION == 2
    assert len(state.apps) <= 1  # a version-1 file names at most one app


def test_a_v1_file_reads_as_its_one_app(tmp_path: Path) -> None:
    state = load_desired(write(tmp_path, "version: 1\napp: {name: rec, params: {A: '1'}}\n"))
    assert [(a.name, a.params) for a in state.apps] == [("rec", {"A": "1"})]
    assert load_desired(write(tmp_path, "version: 1\napp: null\n")).apps == []
    assert load_desired(write(tmp_path, "version: 2\napps: []\n")).apps == []
    assert [a.name for a in load_desired(write(tmp_path, "version: 2\napps: [a, {name: b}]\n"))
            .apps] == ["a", "b"]


@pytest.mark.parametrize(("text", "line", "column", "said"), [
    # a version-1 file's fault is at its own `app.…`, named so, not at the migrated data
    ("version: 1\napp: {name: x, params: {A: 1}}\n", 2, 25, "app.params.A"),
    ("version: 1\napp:\n  name: x\n  user: 'no such user!'\n", 4, 3, "app.user"),
    ("version: 1\n# c\napp:\n  name: x\n  nope: 1\n", 5, 3, "unknown key 'nope'"),
    ("version: 1\napps: [x]\n", 2, 1, "version 1 desired state"),
    # version 2
    ("version: 2\napps:\n  - a\n  - name: b\n    params: {X: 1}\n", 5, 14, "apps.1.params.X"),
    ("version: 2\napps:\n  - name: a\n  - b\n  - a\n", 5, 5, "app a is listed twice"),
    ("version: 2\napp: x\n", 2, 1, "version 2 lists apps under `apps:`"),
])
def test_faults_are_placed_in_the_file_as_written(tmp_path: Path, text: str, line: int,
                                                  column: int, said: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_desired(write(tmp_path, text))
    assert (info.value.line, info.value.column) == (line, column)
    assert said in info.value.message
    assert "apps.0" not in info.value.message


def test_validate_reads_both_versions_and_several_apps(tmp_path: Path) -> None:
    assert "desired state (version 1), read as version 2: 0 repositories, app x" in \
        validate(write(tmp_path, "version: 1\napp: x\n"))
    several = validate(write(tmp_path, "version: 2\napps: [rec, tracker]\n"))
    assert "desired state (version 2): 0 repositories, apps rec, tracker" in several
    assert "is an app catalog" in validate(write(tmp_path, "apps:\n  - name: logger\n"))


SEVERAL = "version: 2\nrepositories: []\napps:\n  - rec\n  - name: tracker\n"


def test_the_v1_schema_stays_frozen_beside_the_rendered_v2() -> None:
    assert "desired-state.v2.schema.json" in DOCUMENTS
    for name, digest in FROZEN.items():
        assert name not in DOCUMENTS
        assert hashlib.sha256((FOLDER / name).read_bytes()).hexdigest() == digest, \
            f"{name} is frozen: fleet repositories' editors validate against it"
    assert "app" in (FOLDER / "desired-state.v1.schema.json").read_text()
    assert "apps" in DesiredState.model_json_schema()["properties"]


# --- edits keep the file's version ---------------------------------------------------------

V1 = "# keep me\nversion: 1\nrepositories: []\napp:\n  name: alpha  # week\n  params: {R: '1'}\n"
V2 = "# keep me\nversion: 2\nrepositories: []\napps:\n  - name: alpha  # week\n" \
     "    params: {R: '1'}\n"


@pytest.fixture
def edited(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """The text an edit would write, caught where it is handed to the apply (that needs
    a catalog and git; the edit itself is what these tests are about)."""
    caught: dict[str, Any] = {}

    def fake(machine: Machine, found: Any, text: str, desired: DesiredState,
             **_: Any) -> editing.Edited:
        caught.update(text=text, desired=desired)
        return editing.Edited(True, Applied(0, "-"))

    monkeypatch.setattr(editing, "_apply", fake)
    return caught


def lines(text: str) -> list[str]:
    """The text's lines, the run of spaces before a comment made one (ruamel keeps a
    comment's column, not its distance from the value)."""
    return [re.sub(r" +#", " #", line) for line in text.splitlines()]


def car(tmp_path: Path, text: str) -> Machine:
    machine = Machine.at(Layout(tmp_path / "root"))
    machine.layout.desired_state.parent.mkdir(parents=True)
    machine.layout.desired_state.write_text(text)
    return machine


def test_an_edit_of_a_v1_file_keeps_version_1(tmp_path: Path, edited: dict[str, Any]) -> None:
    machine = car(tmp_path, V1)
    editing.enable_app(machine, "beta", by="t", options=ApplyOptions(), report=quiet)
    assert lines(edited["text"]) == ["# keep me", "version: 1", "repositories: []", "app:",
                                     "  name: beta # week"]
    editing.set_params(machine, "alpha", {"R": "2"}, by="t", options=ApplyOptions(),
                       report=quiet)
    assert "version: 1\n" in edited["text"] and "apps" not in edited["text"]
    assert [a.params for a in edited["desired"].apps] == [{"R": "2"}]


def test_an_edit_of_a_v2_file_keeps_version_2(tmp_path: Path, edited: dict[str, Any]) -> None:
    machine = car(tmp_path, V2)
    editing.enable_app(machine, "beta", by="t", options=ApplyOptions(), report=quiet)
    assert lines(edited["text"]) == ["# keep me", "version: 2", "repositories: []", "apps:",
                                     "  - name: beta # week"]
    editing.enable_app(machine, None, by="t", options=ApplyOptions(), report=quiet)
    assert edited["text"].endswith("version: 2\nrepositories: []\napps: []\n")
    editing.set_params(machine, "alpha", {"R": "2", "S": "x"}, by="t",
                       options=ApplyOptions(), report=quiet)
    assert "version: 2\n" in edited["text"] and "\napp:" not in edited["text"]
    assert [(a.name, a.params) for a in edited["desired"].apps] == \
        [("alpha", {"R": "2", "S": "x"})]


def test_a_v2_shorthand_is_found_by_name_and_several_become_one(
        tmp_path: Path, edited: dict[str, Any]) -> None:
    machine = car(tmp_path, "version: 2\napps: [rec, tracker]\n")
    editing.set_params(machine, "tracker", {"HZ": "5"}, by="t", options=ApplyOptions(),
                       report=quiet)
    assert [(a.name, a.params) for a in edited["desired"].apps] == \
        [("rec", {}), ("tracker", {"HZ": "5"})]
    editing.enable_app(machine, "rec", by="t", options=ApplyOptions(), report=quiet)
    assert [a.name for a in edited["desired"].apps] == ["rec"]  # the phone knows one app
    assert edited["text"].startswith("version: 2\n")


def test_a_hold_survives_the_upgrade_to_version_2(tmp_path: Path) -> None:
    """A stop or rollback holds while the desired state's fingerprint is unchanged: the
    digest below is the one the lpam before version 2 recorded for this file, so an
    upgraded lpam does not start an app the operator stopped."""
    from reconciler.core.planning.holds import fingerprint as desired_fingerprint

    text = ("version: 1\nrepositories: [{repo: a/b, ref: main}]\napp: {name: x, params: "
            "{A: 'é ü', B: '2'}, user: circles, health: {settle_seconds: 5}}\nmirrors: "
            "{'https://github.com/': 'git://192.168.4.1/'}\nros: {workspace: /home/c/ws}\n"
            "gates: {stationary_seconds: 60, windows: ['22:00-06:00']}\n")
    digest = "3ccf3fad0caf55cd0dd9230ad164f0051e536e249c4bdce8d42bef09febfa134"
    assert desired_fingerprint(load_desired(write(tmp_path, text))) == digest
    v2 = text.replace("version: 1", "version: 2").replace("app: {", "apps: [{") \
        .replace("5}}\n", "5}}]\n")
    assert desired_fingerprint(load_desired(write(tmp_path, v2))) == digest
    assert desired_fingerprint(load_desired(write(tmp_path, "version: 2\napps: [x, y]\n"))) \
        != desired_fingerprint(load_desired(write(tmp_path, "version: 2\napps: [x]\n")))
