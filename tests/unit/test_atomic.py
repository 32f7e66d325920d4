"""write_atomic's power-cut discipline, observed at the system calls it makes.

A power cut can land between any two calls, so their order is the behaviour: the data
must be on disk (fsync of the temp file) before the rename makes it visible, and the
rename must be on disk (fsync of the directory) before lpam goes on as if it were.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from reconciler.base import atomic


def _trace(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, str]]:
    calls: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        calls.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        calls.append(("rename", f"{os.fspath(src)} -> {os.fspath(dst)}"))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    return calls


def test_data_is_synced_before_the_rename_and_the_rename_before_returning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "state.json"
    target.write_text("old\n")
    calls = _trace(monkeypatch)
    atomic.write_atomic(target, "new\n")
    assert target.read_text() == "new\n"
    assert [kind for kind, _ in calls] == ["fsync", "rename", "fsync"]
    temp = calls[0][1]
    assert temp != str(target) and Path(temp).parent == tmp_path  # the data, in a temp file
    assert calls[1][1] == f"{temp} -> {target}"
    assert calls[2][1] == str(tmp_path)  # then the directory entry
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]


def test_a_failed_write_leaves_the_old_file_and_no_temp_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "state.json"
    target.write_text("old\n")

    def no_space(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", no_space)
    with pytest.raises(OSError, match="No space"):
        atomic.write_atomic(target, "new\n")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]


@pytest.mark.parametrize(("asked", "written"), [(0o666, 0o644), (0o775, 0o755),
                                                  (0o600, 0o600)])
def test_what_lpam_writes_no_other_user_may_write_whatever_mode_it_keeps(
    tmp_path: Path, asked: int, written: int
) -> None:
    """An edit keeps the mode of the file it replaces (workflow/editing.py): a desired
    state someone made world-writable comes back writable by its owner alone, and one its
    owner made private stays private."""
    target = tmp_path / "desired-state.yaml"
    atomic.write_atomic(target, "version: 1\n", mode=asked)
    assert target.stat().st_mode & 0o777 == written
