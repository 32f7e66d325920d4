"""A damaged journal never blocks a plan or an apply, and never gives an internal error.

The journal only tells the user which step an interrupted apply was in; the state record
is what lpam trusts. So each kind of damage found by issue 5 is read as "nothing to
report" and, when an apply starts, moved aside with a note.
"""

from __future__ import annotations

import json
import os
import threading
from datetime import datetime, timezone
from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.engine.records.journal import Journal, interrupted_steps, read_events

NOW = datetime(2026, 11, 23, 8, 0, tzinfo=timezone.utc)


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
    "a step id that is not lpam's", "a FIFO",
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
            out.truncate(600 * 1024 * 1024)  # sparse: cheap to make, 600 MB to read
            out.seek(0, os.SEEK_END)
            out.write(b"\n" + begun("x").encode())  # reached only by reading it all
    elif damage == "a FIFO":
        os.mkfifo(path)  # never answers: a plain open would wait for a writer forever
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


@pytest.mark.parametrize("kind", ["a directory", "a FIFO"])
def test_each_damaged_journal_is_kept_aside_under_its_own_name(
    layout: Layout, kind: str
) -> None:
    for attempt in ("first", "second"):  # both within the same second
        layout.journal.unlink(missing_ok=True)  # the fresh journal the first apply wrote
        if kind == "a directory":
            layout.journal.mkdir()
            (layout.journal / "keep").write_text(attempt)
        else:
            os.mkfifo(layout.journal)
        Journal(layout, apply_id=attempt, plan="p").open(NOW)
        assert layout.journal.is_file()
    aside = sorted(p.name for p in layout.journal.parent.iterdir() if ".damaged-" in p.name)
    assert aside == ["journal.jsonl.damaged-20261123T080000",
                     "journal.jsonl.damaged-20261123T080000.1"]
    if kind == "a directory":  # kept whole: a person may have put something there
        assert [(layout.journal.parent / name / "keep").read_text() for name in aside] == [
            "first", "second"]


def test_a_journal_that_cannot_be_moved_aside_is_a_clear_error(
    layout: Layout, monkeypatch: pytest.MonkeyPatch
) -> None:
    layout.journal.mkdir()

    def refuse(src: object, dst: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "rename", refuse)
    with pytest.raises(ConfigError) as raised:
        Journal(layout, apply_id="a", plan="p").open(NOW)
    assert raised.value.path == layout.journal and raised.value.hint


def test_a_link_planted_during_an_apply_is_refused_not_written_through(
    layout: Layout, tmp_path: Path
) -> None:
    journal = Journal(layout, apply_id="a", plan="p")
    journal.open(NOW)
    outside = tmp_path / "outside"
    outside.write_text("precious\n")
    layout.journal.unlink()
    layout.journal.symlink_to(outside)
    with pytest.raises(ConfigError, match="symbolic link"):
        journal.begin("start:alpha@1", NOW)
    assert outside.read_text() == "precious\n"


def test_a_fifo_planted_during_an_apply_never_hangs_it(layout: Layout) -> None:
    journal = Journal(layout, apply_id="a", plan="p")
    journal.open(NOW)
    layout.journal.unlink()
    os.mkfifo(layout.journal)
    raised: list[BaseException] = []

    def begin() -> None:
        try:
            journal.begin("start:alpha@1", NOW)
        except BaseException as exc:  # handed to the test's thread
            raised.append(exc)

    writer = threading.Thread(target=begin, daemon=True)
    writer.start()
    writer.join(timeout=10)
    if writer.is_alive():  # it waits for a reader: give it one, so the test can end
        os.close(os.open(layout.journal, os.O_RDONLY | os.O_NONBLOCK))
        writer.join(timeout=10)
        pytest.fail("the journal write waited on a FIFO")
    assert len(raised) == 1 and isinstance(raised[0], ConfigError)
