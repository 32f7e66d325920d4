"""`libpanda-app-manager`'s own words, without a car: what a user reads when they type
the bare name, what `-t` says of each installed app, and `-d`'s Service column."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from reconciler.base.unit import UnitState
from reconciler.core.privzone.messages import app_info_message
from reconciler.frontends import shim
from reconciler.report.build import build
from reconciler.report.gather import Listing, Seen
from schemas.catalog import CatalogApp
from schemas.record import AppRecord, RepositoryRecord, StateRecord
from schemas.report import InstalledApp, StatusReport, UnitView

COMMIT = "c" * 40


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
                        status="installed",
                        standing="running" if unit is not None else "unverified",
                        said="installed", held=False, good=True,
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


def test_the_service_column_is_never_empty_installed_or_not() -> None:
    """LPAM's `-d` (and the phone's list, from the same rows) showed each app's service
    from its `service` file whether installed or not. An app lpam runs itself has the unit
    lpam writes for it, known before it is installed; an app that names none says so."""
    record = StateRecord(
        repositories=[RepositoryRecord(key="o/apps", url="git://x/o/apps.git", ref="main",
                                       commit=COMMIT, applied=COMMIT)],
        apps=[AppRecord(name="ticker", repository="o/apps", commit=COMMIT, tree="t" * 40,
                        path="ticker/", generation="tic-g1", status="running",
                        service="lpam-app-ticker", command=["python3", "run.py"])])
    listed = (CatalogApp(name="ticker", path="ticker/", command=["python3", "run.py"]),
              CatalogApp(name="tocker", path="apps/tocker/", command=["python3", "run.py"]),
              CatalogApp(name="roslaunched", path="rl", launch="pkg/x.launch"),
              CatalogApp(name="cbf", path="cbf/", service="can"),
              CatalogApp(name="bare", path="bare/"))
    report = build(Seen(record=record, listings=(Listing("o/apps", "main", COMMIT[:12],
                                                         listed),),
                        lives={"ticker": UnitState("lpam-app-ticker", True, "active")}))
    cells = [line.split("\t") for line in shim.lpam_text("d", report).splitlines()[1:]]
    assert [(c[2], c[3], c[4]) for c in cells] == [
        ("ticker", "lpam-app-ticker", "yes"), ("tocker", "lpam-app-tocker", "no"),
        ("roslaunched", "lpam-app-rl", "no"), ("cbf", "can", "no"), ("bare", "none", "no")]
    phone = json.loads(json.loads(b"".join(app_info_message(report.listed()))[:-1])
                       ["contents"])
    assert [r["service"] for r in phone] == [c[3] for c in cells]


def test_help_read_by_a_reader_that_leaves_early_is_no_traceback(tmp_path: Path) -> None:
    """`libpanda-app-manager -h | head -3`: the reader closes the pipe; nothing more is
    said and the exit is 0, as for `lpam plan | head`."""
    done = subprocess.run(
        f"for i in 1 2 3; do {sys.executable} -m reconciler.frontends.shim -h | head -1; done",
        shell=True, capture_output=True, text=True, timeout=60, cwd=tmp_path,
        env={**os.environ, "LPAM_ROOT": str(tmp_path),
             "PYTHONPATH": str(Path(shim.__file__).resolve().parents[2])})
    assert done.stdout.count("usage: libpanda-app-manager") == 3  # a race: three tries
    assert done.stderr == "", done.stderr
