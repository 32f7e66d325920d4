"""Stopping and uninstalling an app the record does not own (a `Stray`: found installed
on disk, or LPAM's app), with its own scripts and the parameters it was found with —
like the lifecycle of the recorded app: intent, script, outcome."""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

from reconciler.base.errors import StepError
from reconciler.core.planning.model import Generation
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps.folders import on_disk, run_script
from reconciler.engine.execution.supervision import await_unit
from schemas.generation import StrayGeneration
from schemas.record import Stray

Leaving = Literal["stop", "uninstall"]


def leave(found: StrayGeneration, what: Leaving, ctx: Context) -> None:
    """Stop or uninstall the stray the step names, if the record still shows it."""
    key = (found.name, found.generation)
    stray = next((s for s in ctx.record.strays if (s.name, s.generation) == key), None)
    if stray is not None:
        _script(ctx, stray, what)


def _script(ctx: Context, stray: Stray, what: Leaving) -> None:
    def replace(new: Stray | None) -> None:
        strays = [s for s in ctx.record.strays if s.generation != stray.generation
                  or s.name != stray.name]
        ctx.save(ctx.record.model_copy(update={"strays": strays + ([new] if new else [])}))

    run = ctx.run_id() if stray.service is None else None
    replace(stray.model_copy(update={"pending": what, "run": run}))
    if stray.folder is not None:  # an app LPAM installed: its own folder, its own scripts
        assert run is not None
        _lpam_script(ctx, stray, stray.folder, what, run, replace)
    elif stray.service is not None:
        if what == "stop":
            ctx.services.stop(stray.service)
        else:
            ctx.services.uninstall(stray.service)
    else:
        assert run is not None
        fallback = Generation(name=stray.name, generation=stray.generation, params=stray.params)
        gen = on_disk(ctx, stray.name, stray.generation, fallback)
        run_script(ctx, gen, f"{what}.sh", stray.params, run)
        if what == "uninstall":
            ctx.app_folders().release(gen.folder,
                           ctx.layout.generation_dir(gen.name, gen.generation))
    replace(None if what == "uninstall" else
            stray.model_copy(update={"stopped": True, "pending": None, "run": None}))


def _lpam_script(ctx: Context, stray: Stray, name: str, what: Leaving, run: str,
                 replace: Callable[[Stray | None], None]) -> None:
    """LPAM's app, in its own folder: its stop.sh's exit code is not trusted."""
    folder = ctx.layout.libpanda_apps / name
    ctx.scripts.run(stray.name, folder, f"{what}.sh", stray.params, run=run)
    unit = ctx.app_folders().service_of(folder)
    if what == "stop" and unit is not None:
        try:
            await_unit(ctx, stray.name, unit, active=False, script="stop.sh")
        except StepError:
            replace(stray.model_copy(update={"pending": what, "run": None}))
            raise
    if what == "uninstall":
        ctx.app_folders().set_current(None)
