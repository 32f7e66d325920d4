"""One contract for every script runner: the real ScriptRunner (bash, process groups, the
guard that writes the exit code) and the MemoryScripts twin of the property tests.

The executor's crash safety rests on three promises checked here for both: a missing
optional script is "nothing to run", a missing required one is an error, and every run
that ends leaves its exit code in `runs/<run>.exit` — the fact a resumed apply trusts.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from reconciler.adapters.memory import MemoryScripts
from reconciler.adapters.scripts import ScriptRunner
from reconciler.base.errors import StepError
from reconciler.engine.execution.ports import Scripts

RUN = "0123456789abcdef0123456789abcdef"

Factory = Callable[[Path], tuple[Scripts, Callable[[Path, str], None]]]


def real(root: Path) -> tuple[Scripts, Callable[[Path, str], None]]:
    runner = ScriptRunner(root=root, log=root / "apply.log", runs=root / "runs", timeout=30)

    def failing(app_dir: Path, script: str) -> None:
        (app_dir / script).write_text("#!/usr/bin/env bash\nexit 1\n")

    return runner, failing


def twin(root: Path) -> tuple[Scripts, Callable[[Path, str], None]]:
    scripts = MemoryScripts(runs_dir=root / "runs")

    def failing(app_dir: Path, script: str) -> None:
        scripts.fail.add(f"alpha:{script}")

    return scripts, failing


@pytest.fixture(params=[real, twin], ids=["bash", "memory"])
def runner(request: pytest.FixtureRequest, tmp_path: Path) -> tuple[
        Scripts, Callable[[Path, str], None], Path]:
    app_dir = tmp_path / "alpha"
    app_dir.mkdir()
    for script in ("install.sh", "start.sh"):
        (app_dir / script).write_text("#!/usr/bin/env bash\ntrue\n")
    factory: Factory = request.param
    scripts, failing = factory(tmp_path)
    return scripts, failing, app_dir


def exit_code(app_dir: Path) -> str:
    return (app_dir.parent / "runs" / f"{RUN}.exit").read_text().strip()


def test_a_script_that_succeeds_leaves_exit_code_zero(
    runner: tuple[Scripts, Callable[[Path, str], None], Path],
) -> None:
    scripts, _, app_dir = runner
    assert scripts.run("alpha", app_dir, "install.sh", {}, run=RUN) is True
    assert exit_code(app_dir) == "0"


def test_a_script_that_fails_is_a_step_error_and_leaves_its_exit_code(
    runner: tuple[Scripts, Callable[[Path, str], None], Path],
) -> None:
    scripts, failing, app_dir = runner
    failing(app_dir, "start.sh")
    with pytest.raises(StepError, match=r"start\.sh"):
        scripts.run("alpha", app_dir, "start.sh", {}, run=RUN)
    assert exit_code(app_dir) == "1"


def test_a_missing_script_is_nothing_to_run_unless_required(
    runner: tuple[Scripts, Callable[[Path, str], None], Path],
) -> None:
    scripts, _, app_dir = runner
    assert scripts.run("alpha", app_dir, "stop.sh", {}, run=RUN) is False
    assert not (app_dir.parent / "runs" / f"{RUN}.exit").exists()
    with pytest.raises(StepError, match="missing"):
        scripts.run("alpha", app_dir, "stop.sh", {}, run=RUN, required=True)
