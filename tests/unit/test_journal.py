"""A damaged journal never blocks a plan or an apply, and never gives an internal error.

The journal only tells the user which step an interrupted apply was in; the state record
is what lpam trusts. So each kind of damage found by issue 5 is read as "nothing to
report" and, when an apply starts, moved aside with a note.
"""

from __future__ import annotations

import json
import os
from datetime import UTC, datetime
from pathlib import Path

import pytest

from reconciler.execution.journal import Journal, interrupted_steps, read_events
from reconciler.layout import Layout

NOW = datetime(2026, 11, 23, 8, 0, tzinfo=UTC)


def begun(step: str) -> str:
    return json.dumps({"v": 1, "event": "begin", "step": step}) + "\n"


@pytest.fixture
def layout(tmp_path: Path) -> Layout:
    layout = Layout(tmp_path / "root")
    layout.journal.parent.mkdir(parents=True)
    return layout


def test_an_interrupted_step_is_found_despite_a_torn_last_line(layout: Layout) -> None:
    layout.journal.write_text(begun("install:alpha@1") + '{"v": 1, "event": "en')
    assert interrupted_steps(layout) == ["install:alpha@1"]


@pytest.mark.parametrize("damage", [
    "invalid utf-8", "nested 100000 deep", "a directory", "a link to a secret", "huge",
    "a step id that is not lpam's",
])
def test_a_damaged_journal_reads_as_nothing_to_report(
    layout: Layout, tmp_path: Path, damage: str
) -> None:
    path = layout.journal
    if damage == "invalid utf-8":
        path.write_bytes(b"\xff\xfe" + begun("x").encode()[:-1] + b"\xc3\n")
    elif damage == "nested 100000 deep":
        path.write_text("[" * 100_000 + "]" * 100_000 + "\n")
    elif damage == "a directory":
        path.mkdir()
    elif damage == "a link to a secret":
        secret = tmp_path / "secret"
        secret.write_text(begun("SECRET"))
        path.symlink_to(secret)
    elif damage == "huge":
        with path.open("wb") as out:
            out.truncate(64 * 1024 * 1024)  # sparse: cheap to make, 64 MiB to read
    else:
        path.write_text(begun("\x1b]0;owned\x07") + begun("x" * 10_000))
    assert interrupted_steps(layout) == []


def test_an_apply_moves_a_journal_that_is_not_a_file_aside(layout: Layout) -> None:
    layout.journal.mkdir()
    (layout.journal / "keep").write_text("whatever was there\n")
    notes: list[str] = []
    journal = Journal(layout, apply_id="a", plan="p")
    journal.open(NOW, warn=notes.append)
    journal.begin("start:alpha@1", NOW)
    assert layout.journal.is_file()
    assert interrupted_steps(layout) == ["start:alpha@1"]
    aside = [p for p in layout.journal.parent.iterdir() if ".damaged-" in p.name]
    assert len(aside) == 1 and (aside[0] / "keep").read_text() == "whatever was there\n"
    assert len(notes) == 1 and str(aside[0]) in notes[0]


def test_a_journal_planted_as_a_link_is_never_written_through(
    layout: Layout, tmp_path: Path
) -> None:
    outside = tmp_path / "outside"
    outside.write_text("precious\n")
    layout.journal.symlink_to(outside)
    journal = Journal(layout, apply_id="a", plan="p")
    journal.open(NOW)
    journal.end("x", NOW)
    assert outside.read_text() == "precious\n"
    assert not layout.journal.is_symlink()
    assert [e["event"] for e in read_events(layout)] == ["apply-begin", "end"]
    assert os.path.exists(layout.journal)
