"""A fault in a JSON document lpam wrote (state record, saved plan) is placed without the
YAML reader, at the line and column the YAML reader would name (issue 32 item 2).

`json_position` walks the text with `json`'s decoder; the property holds it to the YAML
reader's placing — key, item, nearest existing parent — over generated documents in the
shapes lpam writes (indented and compact), so every message that named a place before
names the same place now. The record tests hold what the user sees: the message, the
line and column, and that neither a sound nor a faulty record is composed as YAML.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ruamel.yaml.composer import Composer

from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.base.loading import load
from reconciler.core.written import json_position
from reconciler.engine.records.state import read_record, write_record
from schemas.record import AppRecord, HistoryEntry, RepositoryRecord, StateRecord

_TEXT = st.text(st.characters(codec="utf-8", max_codepoint=0xFFFF), max_size=6)
"""Text `json` writes as YAML reads it: a character past U+FFFF is escaped as a surrogate
pair, which the YAML reader refuses (a fault in it is placed by `json_position` alone)."""
_SCALARS = st.none() | st.booleans() | st.integers() | _TEXT | st.floats(
    allow_nan=False, allow_infinity=False)
_VALUES = st.recursive(_SCALARS, lambda inner: st.lists(inner, max_size=4)
                       | st.dictionaries(_TEXT, inner, max_size=4), max_leaves=25)
_DOCUMENTS = st.dictionaries(_TEXT, _VALUES, min_size=1, max_size=5)
_SHAPES = [{"indent": 2, "sort_keys": True}, {"separators": (",", ":")}, {}]


def paths(value: Any, prefix: tuple[str | int, ...] = ()) -> list[tuple[str | int, ...]]:
    """Every location in `value`, and beside each container one that is not there (a
    missing key, an item past the end): what pydantic's faults name."""
    found = [prefix]
    if isinstance(value, dict):
        found += [(*prefix, "no such key")]
        for key, inner in value.items():
            found += paths(inner, (*prefix, key))
    elif isinstance(value, list):
        found += [(*prefix, len(value)), (*prefix, "key")]
        for index, inner in enumerate(value):
            found += paths(inner, (*prefix, index))
    return found


@settings(deadline=None, max_examples=150)  # a busy machine (a parallel run) is slow
@given(_DOCUMENTS, st.sampled_from(_SHAPES))
def test_a_json_document_is_placed_where_the_yaml_reader_places_it(
        data: dict[str, Any], shape: dict[str, Any]) -> None:
    text = json.dumps(data, **shape)
    doc = load(Path("doc.json"), text)
    for loc in paths(data):
        assert json_position(text, loc) == doc.position(loc), (text, loc)


def _record(apps: int) -> StateRecord:
    return StateRecord(lineage="L", serial=3, repositories=[
        RepositoryRecord(key=f"r{n}", url=f"git://h/r{n}", ref=None, commit="a" * 40)
        for n in range(apps)], apps=[
        AppRecord(name=f"app{n}", repository=f"r{n}", commit="a" * 40, tree="1" * 40,
                  path=f"app{n}", generation="111111111111-00000000", status="running",
                  params={"rate": "10"}) for n in range(apps)])


def _write(tmp_path: Path, record: StateRecord) -> tuple[Layout, str]:
    layout = Layout(tmp_path)
    write_record(layout, record)
    return layout, layout.state_record.read_text()


def _place(text: str, needle: str, nth: int = 1) -> tuple[int, int]:
    """1-based line and column of the `nth` occurrence of `needle`, as an editor shows it."""
    at = -1
    for _ in range(nth):
        at = text.index(needle, at + 1)
    return text.count("\n", 0, at) + 1, at - text.rfind("\n", 0, at)


def _refused(layout: Layout) -> ConfigError:
    with mock.patch.object(Composer, "get_single_node", side_effect=AssertionError(
            "composed as YAML")), pytest.raises(ConfigError) as info:
        read_record(layout)
    return info.value


def test_a_syntax_error_in_the_record_names_its_line_and_column(tmp_path: Path) -> None:
    layout, text = _write(tmp_path, _record(2))
    broken = text.replace('"serial": 4,', '"serial": 4', 1)
    layout.state_record.write_text(broken)
    error = _refused(layout)
    line, column = _place(broken, '"strays"')  # the key after the missing comma
    assert error.message == "not a valid state-record: Expecting ',' delimiter"
    assert (error.path, error.line, error.column) == (layout.state_record, line, column)
    assert f"state.json:{line}:{column}: " in error.render()
    assert "move it aside" in (error.hint or "")


def test_a_wrong_type_deep_in_the_record_is_named_at_its_key(tmp_path: Path) -> None:
    layout, text = _write(tmp_path, _record(3))
    broken = text.replace('"rate": "10"', '"rate": 10', 3)
    layout.state_record.write_text(broken)
    error = _refused(layout)
    assert error.message == "invalid state-record at apps.0.params.rate: Input should be " \
        "a valid string"
    assert (error.line, error.column) == _place(broken, '"rate"')
    assert "move it aside" in (error.hint or "")


def test_a_missing_field_is_named_at_the_entry_it_is_missing_from(tmp_path: Path) -> None:
    layout, text = _write(tmp_path, _record(3))
    entry = json.loads(text)["apps"][2]
    broken = text.replace('"name": "app2"', '"name": "app2", "commit": 1', 1).replace(
        f'"commit": "{entry["commit"]}",', "", 3)
    layout.state_record.write_text(broken)
    error = _refused(layout)
    assert error.message == "invalid state-record at apps.0.commit: Field required"
    assert (error.line, error.column) == _place(broken, "{", 2)  # apps' first entry


def test_a_fault_in_a_record_larger_than_a_yaml_document_is_still_placed(
        tmp_path: Path) -> None:
    """A long-lived car's record (its history) holds more values than the YAML reader
    takes (loading.MAX_VALUES): placed through it, such a fault named no line."""
    history = [HistoryEntry(generation="111111111111-00000000", app="app0", repository="r0",
                            commit="a" * 40, path="app0", tree="1" * 40,
                            time="2026-01-01T00:00:00+00:00", result="applied")] * 700
    record = StateRecord.model_validate({**_record(1).model_dump(),
                                         "history": history})
    layout, text = _write(tmp_path, record)
    broken = text.replace('"status": "running"', '"status": "runnin"', 1)
    layout.state_record.write_text(broken)
    error = _refused(layout)
    assert error.message.startswith("invalid state-record at apps.0.status: Input should be")
    assert (error.line, error.column) == _place(broken, '"status"')
