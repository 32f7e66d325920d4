"""The CLI keeps tracebacks away from users but never loses them."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.frontends import cli


def test_unexpected_error_goes_to_the_debug_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def broken(*_: object) -> int:
        raise RuntimeError("a bug")

    monkeypatch.setitem(cli.COMMANDS, "status", broken)
    assert cli.main(["--root", str(tmp_path), "status"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" in err
    log = tmp_path / "var/log/lpam/debug.log"
    assert "RuntimeError: a bug" in log.read_text()
    assert str(log) in err


def test_root_from_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                               capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("LPAM_ROOT", str(tmp_path))
    (tmp_path / "etc/libpanda.d").mkdir(parents=True)
    (tmp_path / "etc/libpanda.d/app-manifest.csv").write_text("a/b, main\n")
    assert cli.main(["import-lpam"]) == 0
    assert "repo: a/b" in capsys.readouterr().out


def test_a_debug_log_planted_as_a_link_is_not_written_through(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def broken(*_: object) -> int:
        raise RuntimeError("a bug")

    outside = tmp_path / "outside.txt"
    outside.write_text("precious\n")
    root = tmp_path / "root"
    (root / "var/log/lpam").mkdir(parents=True)
    (root / "var/log/lpam/debug.log").symlink_to(outside)
    monkeypatch.setitem(cli.COMMANDS, "status", broken)
    assert cli.main(["--root", str(root), "status"]) == 1
    assert outside.read_text() == "precious\n"
    err = capsys.readouterr().err
    assert "internal error" in err and "could not be written" in err


def test_a_lock_file_planted_as_a_link_or_a_directory_is_refused(tmp_path: Path) -> None:
    from reconciler.base.errors import LockError
    from reconciler.base.layout import Layout
    from reconciler.engine.execution.lock import apply_lock

    layout = Layout(tmp_path)
    outside = tmp_path / "outside.txt"
    outside.write_text("precious\n")
    layout.lock.parent.mkdir(parents=True)
    layout.lock.symlink_to(outside)
    with pytest.raises(LockError, match="symbolic link"), apply_lock(layout, timeout=0):
        pass
    assert outside.read_text() == "precious\n"
    layout.lock.unlink()
    layout.lock.mkdir()
    with pytest.raises(LockError, match="directory"), apply_lock(layout, timeout=0):
        pass
