"""The state record: lineage fixed on first write, serial bumped on each, atomic, versioned."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ConfigError, VersionError
from reconciler.base.layout import Layout
from reconciler.engine.records.state import read_record, settle, write_record
from schemas.record import AppRecord, AppStatus, StateRecord


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
    write_atomic(layout.state_record, json.dumps({"version": 9, "serial": 1}))
    with pytest.raises(VersionError, match="9"):
        read_record(layout)
    write_atomic(layout.state_record, '{"version": 1,\n  "serial": }')
    with pytest.raises(ConfigError) as info:
        read_record(layout)
    assert info.value.line == 2 and "move it aside" in info.value.render()
    write_atomic(layout.state_record, json.dumps({"version": 1, "serial": "x"}))
    with pytest.raises(ConfigError, match="serial"):
        read_record(layout)


def _app(status: AppStatus, run: str | None) -> AppRecord:
    return AppRecord(name="x", repository="r", commit="c" * 40, tree="t" * 40, path="x",
                     generation="0123456789ab-01234567", status=status, run=run)


@pytest.mark.parametrize(("status", "code", "settled"), [
    ("starting", 0, "running"), ("installing", 0, "installed"), ("stopping", 0, "installed"),
    ("uninstalling", 0, None),
    ("starting", 1, "starting"), ("starting", None, "starting"),
    ("uninstalling", 3, "uninstalling"),
])
def test_a_script_that_finished_after_lpam_died_is_accounted_for(
    status: AppStatus, code: int | None, settled: str | None
) -> None:
    record = StateRecord(lineage="L", serial=2, apps=[_app(status, "a" * 32)])
    result = settle(record, exit_code=lambda run: code if run == "a" * 32 else None)
    assert [a.status for a in result.apps] == ([settled] if settled else [])
    assert result.serial == 2  # reading never counts as a write


def test_settling_reads_the_guard_s_exit_file(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    write_record(layout, StateRecord(apps=[_app("starting", "b" * 32)]))
    assert [a.status for a in read_record(layout).apps] == ["starting"]
    layout.runs.mkdir(parents=True)
    layout.run_result("b" * 32).write_text("0\n")
    assert [a.status for a in read_record(layout).apps] == ["running"]


@pytest.mark.parametrize("damage", ["utf8", "directory", "deep", "symlink", "huge"])
def test_a_damaged_record_is_refused_with_a_safe_way_forward(tmp_path: Path, damage: str) -> None:
    layout = Layout(tmp_path)
    path = layout.state_record
    path.parent.mkdir(parents=True)
    if damage == "utf8":
        path.write_bytes(b'{"version": 2, "serial": "\xff"}')
    elif damage == "directory":
        path.mkdir()
    elif damage == "deep":
        path.write_text("[" * 100_000 + "]" * 100_000)
    elif damage == "symlink":
        (tmp_path / "elsewhere.json").write_text(json.dumps({"version": 2}))
        path.symlink_to(tmp_path / "elsewhere.json")
    else:
        path.write_bytes(b" " * (5 * 1024 * 1024))
    with pytest.raises(ConfigError) as info:
        read_record(layout)
    assert info.value.path == path
    assert "move it aside" in (info.value.hint or "") and "uninstalls" in (info.value.hint or "")


def test_without_a_record_generations_on_disk_are_strays(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    gen = "0123456789ab-01234567"
    layout.generation_dir("pandarecord", gen).mkdir(parents=True)
    layout.generation_meta("pandarecord", gen).write_text(json.dumps(
        {"app": "pandarecord", "generation": gen, "params": {"RATE": "5"}}))
    layout.generation_dir("old", "ba9876543210-76543210").mkdir(parents=True)  # no metadata
    strays = read_record(layout).strays
    assert [(s.name, s.generation, s.params) for s in strays] == [
        ("old", "ba9876543210-76543210", {}), ("pandarecord", gen, {"RATE": "5"})]
