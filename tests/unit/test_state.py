"""The state record: lineage fixed on first write, serial bumped on each, atomic, versioned."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from reconciler.atomic import write_atomic
from reconciler.errors import ConfigError, VersionError
from reconciler.layout import Layout
from reconciler.state import read_record, write_record
from schemas.record import StateRecord


def test_empty_machine_then_lineage_and_serial(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    assert read_record(layout) == StateRecord()
    first = write_record(layout, read_record(layout))
    second = write_record(layout, first)
    assert first.lineage and second.lineage == first.lineage
    assert (first.serial, second.serial) == (1, 2)
    assert read_record(layout) == second
    assert [p.name for p in layout.state_record.parent.iterdir()] == ["state.json"]  # no temp


def test_newer_or_corrupt_record_is_refused_by_name(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    write_atomic(layout.state_record, json.dumps({"version": 4, "serial": 1}))
    with pytest.raises(VersionError, match="4"):
        read_record(layout)
    write_atomic(layout.state_record, '{"version": 1,\n  "serial": }')
    with pytest.raises(ConfigError) as info:
        read_record(layout)
    assert info.value.line == 2 and "backup" in info.value.render()
    write_atomic(layout.state_record, json.dumps({"version": 1, "serial": "x"}))
    with pytest.raises(ConfigError, match="serial"):
        read_record(layout)
