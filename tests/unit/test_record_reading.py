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
    """Held at ruamel.yaml's composer itself, not at whichever lpam function calls it:
    any route by which a sound record reaches the YAML reader fails here."""
    from ruamel.yaml.composer import Composer

    layout = Layout(tmp_path)
    a_record(layout)
    with mock.patch.object(Composer, "get_single_node", side_effect=AssertionError(
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


def test_reading_the_record_loads_no_yaml_reader_and_no_other_document_s_model(
        tmp_path: Path) -> None:
    """Every `lpam status` and plan reads the record: in a fresh interpreter, reading it
    (a fault in it included) imports neither the YAML reader nor the models of the
    documents it is not (desired state, catalog, agent settings, plan), so it costs only
    the record's own model (issue 32 item 2)."""
    import json
    import subprocess
    import sys

    a_record(Layout(tmp_path / "sound"))
    a_record(Layout(tmp_path / "faulty"))
    faulty = Layout(tmp_path / "faulty").state_record
    faulty.write_text(faulty.read_text().replace('"running"', "7"))
    script = (
        "import json, sys\n"
        "from pathlib import Path\n"
        "from reconciler.base.errors import ConfigError\n"
        "from reconciler.base.layout import Layout\n"
        "from reconciler.engine.records.state import read_record\n"
        "try:\n"
        "    read_record(Layout(Path(sys.argv[1])))\n"
        "except ConfigError as exc:\n"
        "    print(exc.render(), file=sys.stderr)\n"
        "print(json.dumps(sorted(sys.modules)))\n")
    heavy = {"ruamel.yaml", "schemas.desired", "schemas.catalog", "schemas.agent",
             "schemas.plan"}
    for case in ["sound", "faulty"]:
        done = subprocess.run([sys.executable, "-c", script, str(tmp_path / case)],
                              capture_output=True, text=True, timeout=120, check=True)
        loaded = set(json.loads(done.stdout))
        assert ("apps.0.status" in done.stderr) == (case == "faulty"), done.stderr
        assert "schemas.record" in loaded
        assert not heavy & loaded, f"{case}: {sorted(heavy & loaded)}"
