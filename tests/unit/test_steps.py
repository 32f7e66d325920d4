"""The real lifecycle steps, one at a time, against the in-memory ports.

Each test is a guard the convergence properties never reach on their own because the
planner never asks for it — but a hand-edited or stale plan, or a bug elsewhere, could:
installing beside an installed app, staging a folder whose content is not the planned
one, a stop that is not written down.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import pytest

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import MemoryScripts, MemoryStore
from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.errors import StepError
from reconciler.base.layout import Layout
from reconciler.core.planning.model import generation_id
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps import RUNNERS
from reconciler.engine.records.state import read_record, write_record
from schemas.plan import Phase, StepKind
from schemas.record import AppRecord, StateRecord, Stray
from tests.records import sole
from tests.steps_v1 import step

URL, KEY, COMMIT = "git://h/apps", "lab/apps", "a" * 40
TREES = {"x": "1" * 40, "y": "2" * 40}
FILES = {s: "" for s in ("install.sh", "uninstall.sh", "start.sh", "stop.sh")}
NOW = datetime(2026, 11, 22, tzinfo=timezone.utc)


def machine(tmp_path: Path, record: StateRecord) -> tuple[Context, MemoryScripts]:
    layout = Layout(tmp_path / "root")
    store = MemoryStore(layout=layout, remotes={URL: {COMMIT: {
        a: (t, FILES) for a, t in TREES.items()}}})
    store.fetch(KEY, URL)
    scripts = MemoryScripts(runs_dir=layout.runs)
    if record.lineage is not None or record.strays:
        record = write_record(layout, record)
    return Context(layout=layout, store=store, scripts=scripts, services=MemoryServices(),
                   record=record,
                   clock=lambda: NOW, folders=DiskFolders(layout=layout, store=store)), scripts


def wanted(app: str, *, tree: str | None = None) -> dict[str, str | dict[str, str] | None]:
    return {"app": app, "generation": generation_id(TREES[app], {}), "repository": KEY,
            "commit": COMMIT, "path": app, "tree": tree or TREES[app], "params": {}}


def running(app: str, status: str = "running") -> AppRecord:
    return AppRecord(name=app, repository=KEY, commit=COMMIT, tree=TREES[app], path=app,
                     generation=generation_id(TREES[app], {}), status=status)


def run(kind: StepKind, ctx: Context, **args: str | dict[str, str] | None) -> None:
    phase = Phase.PREPARE if kind is StepKind.STAGE else Phase.CUTOVER
    RUNNERS[kind](step(kind, phase, str(args["app"]), **args), ctx)


@pytest.mark.parametrize("other", ["installed app", "stray"])
def test_install_is_refused_while_another_app_is_installed(tmp_path: Path, other: str) -> None:
    record = (StateRecord(lineage="L", apps=[running("y")]) if other == "installed app" else
              StateRecord(strays=[Stray(name="y", generation=generation_id(TREES["y"], {}))]))
    ctx, scripts = machine(tmp_path, record)
    run(StepKind.STAGE, ctx, **wanted("x"))
    with pytest.raises(StepError, match="refusing to install x: y is still installed"):
        run(StepKind.INSTALL, ctx, **wanted("x"))
    assert scripts.calls == []
    assert read_record(ctx.layout).apps == record.apps


def test_a_staged_folder_whose_content_is_not_the_planned_one_is_refused(
    tmp_path: Path,
) -> None:
    ctx, _ = machine(tmp_path, StateRecord())
    with pytest.raises(StepError, match="not what was planned"):
        run(StepKind.STAGE, ctx, **wanted("x", tree="9" * 40))
    assert not ctx.layout.generation_dir("x", generation_id(TREES["x"], {})).exists()
    assert not any(ctx.layout.generations.glob("x/*"))


def test_a_stop_is_written_down_before_and_after_stop_sh(tmp_path: Path) -> None:
    ctx, scripts = machine(tmp_path, StateRecord(lineage="L"))
    run(StepKind.STAGE, ctx, **wanted("x"))
    run(StepKind.INSTALL, ctx, **wanted("x"))
    run(StepKind.START, ctx, **wanted("x"))
    assert len(read_record(ctx.layout).apps) == 1
    seen: list[str | None] = []
    real_run = scripts.run

    def spy(*args: object, **kwargs: object) -> bool:
        app = sole(read_record(ctx.layout))
        seen.append(app.status if app else None)
        return real_run(*args, **kwargs)  # type: ignore[arg-type]

    scripts.run = spy  # type: ignore[method-assign]
    run(StepKind.STOP, ctx, **wanted("x"))
    after = sole(read_record(ctx.layout))
    assert seen == ["stopping"]  # on disk while stop.sh ran
    assert after is not None and after.status == "installed" and not after.running
    assert scripts.calls == ["x:install.sh", "x:start.sh", "x:stop.sh"]
