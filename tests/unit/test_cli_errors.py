"""The CLI keeps tracebacks away from users but never loses them."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler import cli


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
