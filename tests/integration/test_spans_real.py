"""The span reader on a real recording: the RAV4 Hybrid's 13-minute drive, as `candump -l`
wrote it, and the same frames as libpanda's CSV would hold them (written to the test's
temporary folder). Skipped, saying why, where ../shared/data is not beside the checkout:
the recording states no licence, so no copy of it lives in this repository.
"""

from __future__ import annotations

import os
import time
from datetime import datetime, timezone
from pathlib import Path

import pytest

from reconciler.adapters.spans import finished, span
from tests.canlog import read_log, recorded_path, write_csv


def _recording() -> Path:
    path = recorded_path()
    if not path.is_file():
        pytest.skip(f"the recorded RAV4 drive is not at {path} (../shared/data beside the "
                    "checkout): the generated files of tests/unit/test_spans.py stand in")
    return path


def _stamp(line: str) -> datetime:
    seconds, micro = line[1:line.index(")")].split(".")
    return datetime.fromtimestamp(int(seconds), timezone.utc).replace(microsecond=int(micro))


def test_the_real_candump_log_spans_its_first_and_last_frames_read_at_its_ends(
    monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _recording()
    lines = path.read_text().splitlines()
    sizes: list[int] = []
    real = os.pread

    def pread(fd: int, length: int, offset: int) -> bytes:
        data = real(fd, length, offset)
        sizes.append(len(data))
        return data

    monkeypatch.setattr(os, "pread", pread)
    found = span(path)
    assert (found.first, found.last, found.source) == (
        _stamp(lines[0]), _stamp(lines[-1]), "candump")
    assert sum(sizes) <= 128 * 1024 < path.stat().st_size
    assert finished(path, now=time.time())  # read-only, written long ago, held by no one


def test_the_real_drive_as_libpanda_csv_spans_the_same_moments(tmp_path: Path) -> None:
    frames = read_log(_recording())
    path = tmp_path / "2021-08-13-18-57-47-CAN.csv"
    write_csv(path, frames)
    found = span(path)
    assert found.source == "csv"
    assert found.first is not None and found.last is not None
    assert found.first.timestamp() == pytest.approx(frames[0].timestamp, abs=1e-6)
    assert found.last.timestamp() == pytest.approx(frames[-1].timestamp, abs=1e-6)
