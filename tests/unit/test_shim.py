"""`libpanda-app-manager`'s own words, without a car: what a user reads when they type
the bare name, and what `-t` says of each installed app."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.frontends import shim
from schemas.report import InstalledApp, StatusReport, UnitView


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


def _installed(name: str, unit: UnitView | None) -> InstalledApp:
    return InstalledApp(name=name, repository="fleet/apps", commit="c" * 40,
                        generation="g1", running=unit is not None, verified=unit is not None,
                        status="installed", said="installed", held=False, good=True,
                        unit=unit, claims_known=True)


def test_each_t_line_names_its_app() -> None:
    """Several apps run side by side: a bare `unit can active (running)` does not say
    which app it is about (an app's unit may be named after anything, `can`)."""
    report = StatusReport(installed=[
        _installed("cbf", UnitView(name="can", known=True, active="active", sub="running",
                                   said="unit can active (running)")),
        _installed("recorder", UnitView(name="lpam-app-recorder", known=True,
                                        active="inactive", sub="dead",
                                        said="unit lpam-app-recorder inactive (dead)")),
        _installed("scripted", None),
    ])
    assert shim.lpam_text("t", report).splitlines() == [
        "cbf: unit can active (running)",
        "recorder: unit lpam-app-recorder inactive (dead)",
        "scripted: names no service (no `service` file): lpam's record says installed",
    ]
    assert shim.lpam_text("t", StatusReport()) == "inactive (none installed)\n"  # LPAM's
