"""Reading a sound document lpam wrote (the state record, a plan) parses it once, with
`json`: the second parse, for line and column, is for a fault alone.

Found by tests/reliability/test_consistency.py, whose in-process `lpam status` spent two
thirds of its time parsing the record again as YAML: the version's position was looked
up before the version was known to be fine, on every read — and every `lpam status`,
plan and apply reads the record (on a Pi, several times slower than here).
"""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import pytest

from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.engine.records.state import read_record, write_record
from schemas.record import CURRENT_VERSION, AppRecord, RepositoryRecord, StateRecord


def a_record(layout: Layout) -> None:
    app = AppRecord(name="x", repository="apps", commit="a" * 40, tree="1" * 40, path="x",
                    generation="111111111111-00000000", status="running")
    write_record(layout, StateRecord(lineage="L", serial=3, apps=[app], repositories=[
        RepositoryRecord(key="apps", url="git://h/apps", ref=None, commit="a" * 40)]))


def test_a_sound_record_is_parsed_once(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    a_record(layout)
    with mock.patch("reconciler.core.documents.load", side_effect=AssertionError(
            "parsed again for positions")) as again:
        record = read_record(layout)
    assert [a.name for a in record.apps] == ["x"] and record.lineage == "L"
    assert again.call_count == 0


def test_a_record_of_a_newer_lpam_still_names_the_line_of_its_version(
        tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    a_record(layout)
    text = layout.state_record.read_text()
    written = f'"version": {CURRENT_VERSION}'
    assert written in text
    layout.state_record.write_text(text.replace(written, f'"version": {CURRENT_VERSION + 2}'))
    with pytest.raises(ConfigError) as info:
        read_record(layout)
    line = next(n for n, t in enumerate(text.splitlines(), 1) if '"version"' in t)
    assert "newer lpam" in info.value.message
    assert info.value.line == line
