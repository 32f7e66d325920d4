"""The migration registry and its steps, driven by the before/after fixtures."""

from __future__ import annotations

import copy
import importlib
from pathlib import Path
from typing import Any

import pytest

import migrations
from migrations import (
    CURRENT,
    STEPS,
    agent_status_v1_to_v2,
    desired_state_v0_to_v1,
    desired_state_v1_to_v2,
    generation_meta_v0_to_v1,
    plan_v1_to_v2,
    state_record_v1_to_v2,
    state_record_v2_to_v3,
    state_record_v3_to_v4,
    state_record_v4_to_v5,
    state_record_v5_to_v6,
    state_record_v6_to_v7,
    state_record_v7_to_v8,
    upgrade,
)
from migrations.step import MigrationError
from reconciler.base.errors import ConfigError, VersionError
from reconciler.base.loading import load
from reconciler.core.planning.plan import fingerprint
from schemas.agent import AgentStatus
from schemas.desired import DesiredState
from schemas.generation import GenerationMeta
from schemas.kinds import DocumentKind
from schemas.plan import Plan
from schemas.record import StateRecord

FIXTURES = Path(migrations.__file__).parent / "fixtures"
# Every registered step and the fixture folder that proves it.
STEP_FIXTURES = {
    ("desired-state", "0.0"): FIXTURES / "desired-state" / "v0_to_v1",
    ("desired-state", "1"): FIXTURES / "desired-state" / "v1_to_v2",
    ("state-record", "1"): FIXTURES / "state-record" / "v1_to_v2",
    ("state-record", "2"): FIXTURES / "state-record" / "v2_to_v3",
    ("state-record", "3"): FIXTURES / "state-record" / "v3_to_v4",
    ("state-record", "4"): FIXTURES / "state-record" / "v4_to_v5",
    ("state-record", "5"): FIXTURES / "state-record" / "v5_to_v6",
    ("state-record", "6"): FIXTURES / "state-record" / "v6_to_v7",
    ("state-record", "7"): FIXTURES / "state-record" / "v7_to_v8",
    ("agent-status", "1"): FIXTURES / "agent-status" / "v1_to_v2",
    ("plan", "1"): FIXTURES / "plan" / "v1_to_v2",
    ("generation-meta", "0"): FIXTURES / "generation-meta" / "v0_to_v1",
    ("car-status", "0"): FIXTURES / "car-status" / "v0_to_v1",
    ("car-status", "1"): FIXTURES / "car-status" / "v1_to_v2",
    ("car-status", "2"): FIXTURES / "car-status" / "v2_to_v3",
}
PATH = Path("doc.yaml")


def pairs(folder: Path) -> list[tuple[Path, Path]]:
    befores = sorted(folder.glob("*.before.yaml"))
    return [(b, b.with_name(b.name.replace(".before.", ".after."))) for b in befores]


V0_PAIRS = pairs(STEP_FIXTURES[("desired-state", "0.0")])
RECORD_PAIRS = pairs(STEP_FIXTURES[("state-record", "1")])
RECORD_V3_PAIRS = pairs(STEP_FIXTURES[("state-record", "2")])
RECORD_V4_PAIRS = pairs(STEP_FIXTURES[("state-record", "3")])
RECORD_V5_PAIRS = pairs(STEP_FIXTURES[("state-record", "4")])
RECORD_V6_PAIRS = pairs(STEP_FIXTURES[("state-record", "5")])
RECORD_V7_PAIRS = pairs(STEP_FIXTURES[("state-record", "6")])
RECORD_V8_PAIRS = pairs(STEP_FIXTURES[("state-record", "7")])
AGENT_STATUS_V2_PAIRS = pairs(STEP_FIXTURES[("agent-status", "1")])
PLAN_V2_PAIRS = pairs(STEP_FIXTURES[("plan", "1")])
META_V1_PAIRS = pairs(STEP_FIXTURES[("generation-meta", "0")])


def read(path: Path) -> Any:
    return load(path).data


def test_every_step_has_fixtures_and_a_docstring() -> None:
    for kind, steps in STEPS.items():
        for source, (_, step) in steps.items():
            folder = STEP_FIXTURES[(kind, source)]
            assert pairs(folder), f"no fixtures for {kind} {source}"
            module = importlib.import_module(step.__module__)
            assert module.__doc__ and "why" in module.__doc__.lower()
            assert step.__doc__


def test_every_chain_ends_at_current() -> None:
    for kind, steps in STEPS.items():
        for version in steps:
            seen = set()
            while version != str(CURRENT[kind]):
                assert version not in seen, f"cycle in {kind} steps"
                seen.add(version)
                version = steps[version][0]


@pytest.mark.parametrize(("before", "after"), V0_PAIRS, ids=lambda p: p.name)
def test_v0_to_v1_step_matches_fixture(before: Path, after: Path) -> None:
    data = read(before)
    original = copy.deepcopy(data)
    assert desired_state_v0_to_v1.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"


@pytest.mark.parametrize(("before", "after"), V0_PAIRS, ids=lambda p: p.name)
def test_upgrade_chain_matches_fixture_and_validates(before: Path, after: Path) -> None:
    result = upgrade("desired-state", read(before), path=before)
    assert result == desired_state_v1_to_v2.upgrade(read(after))  # the chain goes on to 2
    DesiredState.model_validate(result)


@pytest.mark.parametrize(("before", "after"), RECORD_PAIRS, ids=lambda p: p.name)
def test_state_record_v1_to_v2_matches_fixture_and_validates(before: Path, after: Path) -> None:
    data = read(before)
    original = copy.deepcopy(data)
    assert state_record_v1_to_v2.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    record = StateRecord.model_validate(upgrade("state-record", data, path=before))
    assert [a.running for a in record.apps] == \
        ([data["app"]["running"]] if data["app"] else [])


@pytest.mark.parametrize(("before", "after"), RECORD_V3_PAIRS, ids=lambda p: p.name)
def test_state_record_v2_to_v3_matches_fixture_and_validates(before: Path, after: Path) -> None:
    data = read(before)
    original = copy.deepcopy(data)
    assert state_record_v2_to_v3.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    record = StateRecord.model_validate(upgrade("state-record", data, path=before))
    assert record.history == [] and record.last_apply is None
    assert all(a.status == data["app"]["status"] and not a.held and a.service is None
               for a in record.apps)


@pytest.mark.parametrize(("before", "after"), RECORD_V4_PAIRS, ids=lambda p: p.name)
def test_state_record_v3_to_v4_matches_fixture_and_validates(before: Path, after: Path) -> None:
    data = read(before)
    original = copy.deepcopy(data)
    assert state_record_v3_to_v4.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    record = StateRecord.model_validate(upgrade("state-record", data, path=before))
    assert record.cutover is None
    # an app the old rules installed was taken for good: it stays a rollback target
    assert all(a.good for a in record.apps)


@pytest.mark.parametrize(("before", "after"), RECORD_V5_PAIRS, ids=lambda p: p.name)
def test_state_record_v4_to_v5_matches_fixture_and_validates(before: Path, after: Path) -> None:
    """One app becomes the one-app set, wherever the record named one (installed, the
    app a cutover returns to, the app a rollback found failing): the same car, listed."""
    data = read(before)
    original = copy.deepcopy(data)
    assert state_record_v4_to_v5.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    record = StateRecord.model_validate(upgrade("state-record", data, path=before))
    assert [a.name for a in record.apps] == ([data["app"]["name"]] if data["app"] else [])
    cutover = data["cutover"]
    if cutover is not None:
        assert record.cutover is not None
        assert [a.name for a in record.cutover.previous] == \
            ([cutover["previous"]["name"]] if cutover["previous"] else [])


@pytest.mark.parametrize(("before", "after"), RECORD_V6_PAIRS, ids=lambda p: p.name)
def test_state_record_v5_to_v6_matches_fixture_and_validates(before: Path, after: Path) -> None:
    """A hold names the set it returns to and nothing else: version 5's one app
    (`target`) becomes a set of one, several stay as they were, and the fingerprint it
    holds against is kept, so the hold still holds after the upgrade."""
    data = read(before)
    original = copy.deepcopy(data)
    assert state_record_v5_to_v6.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    record = StateRecord.model_validate(upgrade("state-record", data, path=before))
    hold = data["hold"]
    if hold is None:
        assert record.hold is None
        return
    assert record.hold is not None and record.hold.desired == hold["desired"]
    named = hold.get("targets") or ([hold["target"]] if hold.get("target") else [])
    assert [e.generation for e in record.hold.targets] == [e["generation"] for e in named]


@pytest.mark.parametrize(("before", "after"), RECORD_V7_PAIRS, ids=lambda p: p.name)
def test_state_record_v6_to_v7_matches_fixture_and_validates(before: Path, after: Path) -> None:
    """The last apply is kept as version 6 wrote it: an `in progress` still reads as live
    or cut off by its pid, and nothing becomes `deferred` that was not written so."""
    data = read(before)
    original = copy.deepcopy(data)
    assert state_record_v6_to_v7.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    record = StateRecord.model_validate(upgrade("state-record", data, path=before))
    last = data["last_apply"]
    if last is None:
        assert record.last_apply is None
        return
    assert record.last_apply is not None
    assert (record.last_apply.result, record.last_apply.pid, record.last_apply.gates,
            record.last_apply.retry) == (last["result"], last.get("pid"), [], None)
    assert record.model_dump(mode="json")["last_apply"] == \
        {"pid": None, "command": None, **last}, "a version-6 last apply is written as it was"


def test_state_record_v6_to_v7_refuses_a_last_apply_that_is_no_mapping() -> None:
    with pytest.raises(MigrationError):
        state_record_v6_to_v7.upgrade({"version": 6, "last_apply": "in progress"})


@pytest.mark.parametrize(("before", "after"), RECORD_V8_PAIRS, ids=lambda p: p.name)
def test_state_record_v7_to_v8_matches_fixture_and_validates(before: Path, after: Path) -> None:
    """A version-7 record does not know who made its changes: nothing is guessed (no
    `by` anywhere), and it is written back exactly as version 7 wrote it, but for its
    version."""
    data = read(before)
    original = copy.deepcopy(data)
    assert state_record_v7_to_v8.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    record = StateRecord.model_validate(upgrade("state-record", data, path=before))
    assert all(entry.by is None for entry in record.history)
    assert record.last_apply is None or record.last_apply.by is None
    written = record.model_dump(mode="json")
    assert written["history"] == data["history"], "an unknown actor is not written"
    assert "by" not in (written["last_apply"] or {})


@pytest.mark.parametrize("history", ["applied", [1], [None]])
def test_state_record_v7_to_v8_refuses_a_history_that_is_no_list_of_mappings(
        history: Any) -> None:
    with pytest.raises(MigrationError):
        state_record_v7_to_v8.upgrade({"version": 7, "history": history})


@pytest.mark.parametrize(("before", "after"), AGENT_STATUS_V2_PAIRS, ids=lambda p: p.name)
def test_agent_status_v1_to_v2_matches_fixture_and_validates(before: Path, after: Path) -> None:
    data = read(before)
    original = copy.deepcopy(data)
    assert agent_status_v1_to_v2.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    status = AgentStatus.model_validate(upgrade("agent-status", data, path=before))
    # never published under the new rules: the next online pass publishes
    assert status.publication is None and status.follows is None
    assert status.passes == AgentStatus.model_validate(read(after)).passes


def _plan_v1(path: Path) -> dict[str, Any]:
    """A saved version-1 plan as the registry sees it (`version` is its `format_version`)."""
    data = dict(read(path))
    data["version"] = data.pop("format_version")
    return data


@pytest.mark.parametrize(("before", "after"), PLAN_V2_PAIRS, ids=lambda p: p.name)
def test_plan_v1_to_v2_matches_fixture_and_its_seal_holds(before: Path, after: Path) -> None:
    """The `before` plans were written and sealed by the lpam before typed steps."""
    data = _plan_v1(before)
    original = copy.deepcopy(data)
    assert plan_v1_to_v2.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    result = upgrade("plan", data, path=before)
    result["format_version"] = result.pop("version")
    plan = Plan.model_validate(result)
    assert plan.fingerprint == fingerprint(plan)  # sealed again over the typed steps


@pytest.mark.parametrize(("edit", "loc"), [
    (lambda d: d["steps"][0]["args"].update(commit="f" * 40), ("fingerprint",)),
    (lambda d: d.update(serial=d["serial"] + 1), ("fingerprint",)),
    (lambda d: d.update(fingerprint="0" * 64), ("fingerprint",)),
])
def test_an_edited_v1_plan_is_refused_on_its_v1_seal(edit: Any, loc: tuple[str, ...]) -> None:
    data = _plan_v1(PLAN_V2_PAIRS[0][0])
    edit(data)
    with pytest.raises(MigrationError, match="fingerprint does not match") as info:
        plan_v1_to_v2.upgrade(data)
    assert info.value.loc == loc


def test_a_sealed_v1_plan_whose_step_cannot_be_carried_is_located() -> None:
    """A seal is no secret: a plan resealed by hand with a broken step is still refused,
    at the step."""
    data = _plan_v1(PLAN_V2_PAIRS[0][0])
    data["steps"][1]["args"] = "junk"
    data["fingerprint"] = plan_v1_to_v2._seal(plan_v1_to_v2._body(data, 1, data["steps"]))
    with pytest.raises(MigrationError, match="step 2") as info:
        plan_v1_to_v2.upgrade(data)
    assert info.value.loc == ("steps", 1)


@pytest.mark.parametrize(("before", "after"), META_V1_PAIRS, ids=lambda p: p.name)
def test_generation_meta_v0_to_v1_matches_fixture_and_validates(before: Path,
                                                                after: Path) -> None:
    data = read(before)
    original = copy.deepcopy(data)
    assert generation_meta_v0_to_v1.upgrade(data) == read(after)
    assert data == original, "a step must not modify its input"
    meta = GenerationMeta.model_validate(
        upgrade("generation-meta", {**data, "version": 0}, path=before))
    assert (meta.name, meta.generation) == (data["app"], data["generation"])


def test_an_agent_status_v1_claiming_v2_fields_is_refused() -> None:
    with pytest.raises(ConfigError) as info:
        upgrade("agent-status", {"version": 1, "follows": "x.yaml"}, path=PATH)
    assert "follows" in info.value.message


def test_state_record_v1_with_a_bad_flag_is_located() -> None:
    doc = load(PATH, "version: 1\napp:\n  name: x\n  running: maybe\n")
    with pytest.raises(ConfigError) as info:
        upgrade("state-record", doc.data, path=PATH, position=doc.position)
    assert (info.value.line, info.value.column) == (4, 3)


@pytest.mark.parametrize("version", [2, "2", " 2 "])
def test_current_version_passes_through(version: object) -> None:
    data = {"version": version, "repositories": [{"repo": "a/b"}], "apps": ["x"]}
    result = upgrade("desired-state", data, path=PATH)
    assert result == {"version": 2, "repositories": [{"repo": "a/b"}], "apps": ["x"]}
    assert data["version"] == version


@pytest.mark.parametrize("kind", sorted(CURRENT))
def test_newer_version_is_refused_naming_both(kind: DocumentKind) -> None:
    with pytest.raises(VersionError) as info:
        upgrade(kind, {"version": 9}, path=PATH)
    message = info.value.message
    assert "newer lpam" in message
    assert "document version 9" in message
    assert f"reads up to {CURRENT[kind]}" in message
    assert info.value.hint == "upgrade lpam"


def test_newer_version_position_comes_from_the_document() -> None:
    doc = load(PATH, "# a comment\napp: x\nversion: 3\n")
    with pytest.raises(VersionError) as info:
        upgrade("desired-state", doc.data, path=PATH, position=doc.position)
    assert (info.value.line, info.value.column) == (3, 1)
    assert info.value.path == PATH


@pytest.mark.parametrize("data", [{}, {"app": "x"}, {"version": None}])
def test_missing_version(data: dict[str, Any]) -> None:
    with pytest.raises(ConfigError) as info:
        upgrade("desired-state", data, path=PATH)
    assert not isinstance(info.value, VersionError)
    assert (info.value.path, info.value.line, info.value.column) == (PATH, 1, 1)
    assert "version" in info.value.message
    assert info.value.hint is not None
    assert "version: 1" in info.value.hint
    assert "import-lpam" in info.value.hint


@pytest.mark.parametrize("kind", ["state-record", "plan"])
def test_missing_version_of_other_kinds_has_a_hint(kind: str) -> None:
    with pytest.raises(ConfigError) as info:
        upgrade(kind, {"serial": 1}, path=PATH)
    assert info.value.hint


@pytest.mark.parametrize("data", [[1, 2], "text", 3, None])
def test_non_mapping(data: object) -> None:
    with pytest.raises(ConfigError) as info:
        upgrade("desired-state", data, path=PATH)
    assert (info.value.line, info.value.column) == (1, 1)
    assert info.value.message.startswith("expected a mapping")


@pytest.mark.parametrize(
    ("version", "shown"), [(0.5, "0.5"), ("0.1", "0.1"), (0, "0"), (1.0, "1.0")]
)
def test_unknown_older_version_is_named(version: object, shown: str) -> None:
    with pytest.raises(VersionError) as info:
        upgrade("desired-state", {"version": version}, path=PATH)
    assert f"version {shown};" in info.value.message
    assert "0.0, 1" in info.value.message


@pytest.mark.parametrize("version", [True, "one", [1], float("nan"), "1e3"])
def test_version_that_is_not_a_number(version: object) -> None:
    with pytest.raises(VersionError) as info:
        upgrade("desired-state", {"version": version}, path=PATH)
    assert "must be a number" in info.value.message


def test_plans_know_versions_1_and_2() -> None:
    assert upgrade("plan", {"version": 2, "serial": 4}, path=PATH) == {"version": 2, "serial": 4}
    with pytest.raises(VersionError):
        upgrade("plan", {"version": "0.0"}, path=PATH)


def test_unknown_kind_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match="unknown document kind"):
        upgrade("catalog", {"version": 1}, path=PATH)


@pytest.mark.parametrize(
    ("text", "line", "column", "words"),
    [
        ("version: 0.0\nrepositories:\n  ../x:\n    branch: main\n", 3, 3, "'../x'"),
        ("version: 0.0\nrepositories:\n  'a;rm -rf/x': {branch: main}\n", 3, 3, "a;rm -rf"),
        ("version: 0.0\nrepositories:\n  a/b:\n    branch: '-x'\n", 4, 5, "branch"),
        ("version: 0.0\nrepositories:\n  a/b:\n    branch: [main]\n", 4, 5, "string"),
        ("version: 0.0\nrepositories:\n  a/b:\n    tag: v1\n", 4, 5, "'tag'"),
        ("version: 0.0\nrepositories: [a/b]\n", 2, 1, "map"),
        ("version: 0.0\ncurrent: ../etc\n", 2, 1, "app name"),
        ("version: 0.0\ncurrent: [a]\n", 2, 1, "current"),
        ("version: 0.0\nextra: 1\n", 2, 1, "'extra'"),
    ],
)
def test_step_errors_point_into_the_old_document(
    text: str, line: int, column: int, words: str
) -> None:
    doc = load(PATH, text)
    with pytest.raises(ConfigError) as info:
        upgrade("desired-state", doc.data, path=PATH, position=doc.position)
    assert (info.value.path, info.value.line, info.value.column) == (PATH, line, column)
    assert words in info.value.message
    assert "Traceback" not in info.value.render()


def test_step_error_without_position_has_no_line() -> None:
    with pytest.raises(ConfigError) as info:
        upgrade("desired-state", {"version": 0.0, "current": "../x"}, path=PATH)
    assert info.value.line is None


def test_step_raises_migration_error_with_location() -> None:
    with pytest.raises(MigrationError) as info:
        desired_state_v0_to_v1.upgrade({"repositories": {"a/b": {"branch": "a b"}}})
    assert info.value.loc == ("repositories", "a/b", "branch")
    assert info.value.hint


def test_every_document_kind_has_a_version_a_chain_a_label_and_a_hint() -> None:
    """The registry is closed over DocumentKind: a kind added without its entries fails
    here, not on the first document of that kind a car reads."""
    from migrations.registry import _LABELS, _MISSING_HINTS

    for registry in (CURRENT, STEPS, _LABELS, _MISSING_HINTS):
        assert set(registry) == set(DocumentKind)
