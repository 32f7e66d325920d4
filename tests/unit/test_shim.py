"""`libpanda-app-manager`'s own words, without a car: what a user reads when they type
the bare name."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.frontends import shim


def test_the_bare_name_prints_the_usage_and_exits_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """LPAM opened a menu; the README and `-h` promise the usage instead (exit 2: a usage
    error, nothing done)."""
    monkeypatch.setenv("LPAM_ROOT", str(tmp_path))
    assert shim.main([]) == 2
    out = capsys.readouterr()
    assert out.out == ""
    assert out.err.startswith(shim.USAGE + "\n")
    assert out.err.splitlines()[-1] == (
        "libpanda-app-manager: error: no flag given (LPAM's interactive menu is gone): "
        "give one of the flags above")
    assert list(tmp_path.iterdir()) == []  # nothing done

