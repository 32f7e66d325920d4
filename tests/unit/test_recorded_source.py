"""A log python-can reads whole: a damaged record ends it (what came before counts, the
record is counted as skipped), but a file that cannot be read is no damaged record — it is
an error that says the file cannot be read and what to do."""

from __future__ import annotations

import errno
import gzip
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType

import can
import pytest

from reconciler.adapters.can.sources import RecordedSource
from reconciler.base.errors import VehicleSourceError

FRAME = can.Message(timestamp=100.0, arbitration_id=0xB4, data=b"\0" * 8)


class Reader:
    """python-can's LogReader over a file that yields one frame, then fails with `error`."""

    error: BaseException = ValueError("unset")

    def __init__(self, path: Path) -> None:
        self.path = path

    def __enter__(self) -> Reader:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        pass

    def stop(self) -> None:
        pass

    def __iter__(self) -> Iterator[can.Message]:
        yield FRAME
        raise self.error


def backlog(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, error: BaseException
            ) -> tuple[RecordedSource, list[can.Message]]:
    monkeypatch.setattr(Reader, "error", error)
    monkeypatch.setattr(can, "LogReader", Reader)
    source = RecordedSource(tmp_path / "drive.blf")
    return source, source.backlog(10.0)


@pytest.mark.parametrize("error", [ValueError("bad record"),
                                   gzip.BadGzipFile("Not a gzipped file")])
def test_a_damaged_record_ends_the_log_and_is_counted(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, error: Exception) -> None:
    source, frames = backlog(monkeypatch, tmp_path, error)
    assert frames == [FRAME] and source.skipped == 1


@pytest.mark.parametrize(("error", "said"), [
    (PermissionError(errno.EACCES, "Permission denied"), "permission denied"),
    (OSError(errno.EIO, "Input/output error"), "Input/output error"),
])
def test_a_file_that_cannot_be_read_says_so(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, error: OSError, said: str) -> None:
    with pytest.raises(VehicleSourceError, match=f"cannot read {tmp_path}/drive.blf: {said}"):
        backlog(monkeypatch, tmp_path, error)


def test_a_gate_reading_a_log_it_cannot_read_has_no_signal_and_says_why(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from reconciler.adapters.gate import VehicleGate
    from reconciler.base.layout import Layout
    from schemas.vehicle import GatesSpec, VehicleSpec

    (tmp_path / "drive.blf").write_bytes(b"LOGG")
    monkeypatch.setattr(Reader, "error", OSError(errno.EIO, "Input/output error"))
    monkeypatch.setattr(can, "LogReader", Reader)
    gate = VehicleGate(GatesSpec(), VehicleSpec.model_validate({"source": {"log": "drive.blf"}}),
                       layout=Layout(tmp_path), base_dir=tmp_path)
    vehicle = gate.states()[0]
    assert not vehicle.open
    assert f"cannot read {tmp_path}/drive.blf: Input/output error" in vehicle.detail
