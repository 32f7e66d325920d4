"""The app's lifecycle steps: stage, install, configure, start, stop, uninstall, adopt.

Intent, work, outcome: each writes to the state record before its script (or the unit
lpam wrote) runs and after it ends, so the record never claims more than is known. A
stop or an uninstall of an app the record does not own goes to engine/execution/steps/strays.py.
"""

from __future__ import annotations

import getpass
from pathlib import Path
from typing import Literal

from reconciler.base.errors import ServiceError, StepError
from reconciler.base.unit import unit_name
from reconciler.core.planning.model import Generation, app_folder
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps.folders import (
    as_record,
    installed,
    of_record,
    place,
    run_script,
    staged,
    with_runtime,
)
from reconciler.engine.execution.steps.strays import leave
from reconciler.engine.execution.supervision import await_unit, runtime, unit_for
from schemas.plan import (
    AdoptStep,
    ConfigureStep,
    InstallStep,
    StageStep,
    StartStep,
    StopStep,
    UninstallStep,
)
from schemas.record import AppRecord, AppStatus, StateRecord


def stage(step: StageStep, ctx: Context) -> None:
    """Copy the app folder at its commit into an immutable generation directory; for a
    scriptless app, have the service manager check the unit it will run (a unit that
    cannot run is refused now, while the old app still runs, not after it was stopped)."""
    gen = staged(step.app, step.id, ctx)
    folder = ctx.app_folders().stage(gen)
    if gen.scriptless:
        try:
            ctx.services.check(unit_for(ctx, as_record(gen, step.app.user), folder,
                                        runtime(ctx, gen)))
        except ServiceError as exc:
            raise StepError(f"{gen.name}: {exc.message}", hint=exc.hint) from None


What = Literal["install", "start", "stop", "uninstall"]


def _lifecycle(ctx: Context, app: AppRecord, what: What, during: AppStatus,
               after: AppStatus | None) -> None:
    """Intent, work, outcome: the record never claims more than is known. The work is the
    app's script (then the unit it names is checked), or the unit lpam wrote for it."""
    run = ctx.run_id() if not app.scriptless else None
    ctx.save_app(app.name, app.model_copy(update={"status": during, "run": run}))
    gen = of_record(ctx, app)
    if app.scriptless:
        _unit_work(ctx, app, gen, what)
    else:
        assert run is not None
        run_script(ctx, gen, f"{what}.sh", app.params, run)
        if app.service is not None and what in ("start", "stop"):
            try:
                await_unit(ctx, app.name, app.service, active=what == "start",
                           script=f"{what}.sh")
            except StepError:
                # The script ended with 0, but the unit says it did not do its work: the
                # record must not be settled from that exit code (engine/records/state.py).
                ctx.save_app(app.name, app.model_copy(update={"status": during, "run": None}))
                raise
    ctx.save_app(app.name, None if after is None else
                 app.model_copy(update={"status": after, "run": None}))


def _unit_work(ctx: Context, app: AppRecord, gen: Generation, what: What) -> None:
    """The lifecycle of a unit lpam writes: install writes it, uninstall removes it."""
    name = app.service or unit_name(gen.folder)
    if what == "install":
        ctx.services.install(unit_for(ctx, app, place(ctx, gen), runtime(ctx, gen)))
    elif what == "start":
        ctx.services.start(name)
        await_unit(ctx, app.name, name, active=True, script=None)
    elif what == "stop":
        ctx.services.stop(name)
    else:
        ctx.services.uninstall(name)


def stop(step: StopStep, ctx: Context) -> None:
    if step.stray is not None:
        leave(step.stray, "stop", ctx)
        return
    assert step.app is not None  # one of the two (schemas/plan.py)
    _lifecycle(ctx, installed(step.app, step.id, ctx), "stop", "stopping", "installed")


def uninstall(step: UninstallStep, ctx: Context) -> None:
    if step.stray is not None:
        leave(step.stray, "uninstall", ctx)
        return
    assert step.app is not None  # one of the two (schemas/plan.py)
    # The generation stays until the apply succeeds: a failed cutover reinstalls it.
    app = installed(step.app, step.id, ctx)
    _lifecycle(ctx, app, "uninstall", "uninstalling", None)
    folders = ctx.app_folders()
    folders.release(app_folder(app.path), ctx.layout.generation_dir(app.name, app.generation))
    folders.set_current(current_folder(ctx.record))


def install(step: InstallStep, ctx: Context) -> None:
    gen = with_runtime(ctx, staged(step.app, step.id, ctx))
    other = _in_the_way(ctx.record, gen)
    if other is not None:
        raise StepError(
            f"refusing to install {gen.name}: {other} is still installed",
            hint="only one app may own an exclusive resource (the vehicle's CAN hardware "
            "above all); run `lpam plan` again",
        )
    if not ctx.layout.generation_dir(gen.name, gen.generation).is_dir():
        raise StepError(f"{gen.name}: generation {gen.generation} was not staged")
    app = as_record(gen, step.app.user).model_copy(update={"good": step.good})
    ctx.app_folders().set_current(current_folder(ctx.record.with_app(app.name, app)))
    if gen.ros_build is not None and gen.ros_workspace is not None:
        # the field's scripts look for the sources in the workspace's own src/
        user = gen.ros_user or getpass.getuser()
        workspace = ctx.dependencies().workspace(Path(gen.ros_workspace), user)
        workspace.link(gen.ros_build, sorted(gen.ros))
    _lifecycle(ctx, app, "install", "installing", "installed")


def _in_the_way(record: StateRecord, gen: Generation) -> str | None:
    """What must be gone before `gen` is installed: a stray (it may hold anything), an
    installed app that claims one of its resources (an app whose claims are not known
    holds the panda), or another generation of itself. The same generation cut off while
    installing or uninstalling is redone."""
    if record.strays:
        return record.strays[0].name
    for app in record.apps:
        if app.name == gen.name:
            redo = app.generation == gen.generation and \
                app.status in ("installing", "uninstalling")
            if not redo:
                return app.name
        elif app.claims & gen.claims:
            return app.name
    return None


def current_folder(record: StateRecord) -> str | None:
    """LPAM's `current` app (its manifest and app file, kept true where LPAM left them):
    the app that owns the panda, else the first installed."""
    apps = record.apps
    owner = next((a for a in apps if "panda" in a.claims), apps[0] if apps else None)
    return None if owner is None else app_folder(owner.path)


def adopt(step: AdoptStep, ctx: Context) -> None:
    """LPAM's app is the desired one as it is: its record becomes lpam's (running if its
    unit ran), then its path leads to the generation staged from git (same files; LPAM's
    copy is moved aside, not deleted). No script runs: nothing that runs is touched."""
    gen = staged(step.app, step.id, ctx)
    where = ctx.layout.generation_dir(gen.name, gen.generation)
    if not where.is_dir():
        raise StepError(f"{gen.name}: generation {gen.generation} was not staged")
    status: AppStatus = "running" if step.running else "installed"
    app = as_record(gen, step.app.user).model_copy(update={"status": status, "good": True})
    others = [s for s in ctx.record.strays if s.folder != step.folder]
    ctx.save(ctx.record.with_app(app.name, app).model_copy(update={"strays": others}))
    folders = ctx.app_folders()
    folders.point(gen.folder, where)
    folders.set_current(current_folder(ctx.record))


def configure(step: ConfigureStep, ctx: Context) -> None:
    """New parameters (or user) for the installed generation; a unit lpam wrote is
    rewritten so that its next start has them."""
    app = installed(step.app, step.id, ctx).model_copy(
        update={"params": dict(step.app.params), "user": step.app.user, "good": step.good})
    if app.scriptless and app.status not in ("installing", "uninstalling"):
        gen = of_record(ctx, app)
        ctx.services.install(unit_for(ctx, app, place(ctx, gen), runtime(ctx, gen)))
    ctx.save_app(app.name, app)


def start(step: StartStep, ctx: Context) -> None:
    """`good`: whether the app counts as good once started (core/planning/lifecycle.py decides:
    a generation proved good before, or an apply with nothing to check)."""
    app = installed(step.app, step.id, ctx)
    good = app.good or step.good
    started = app.model_copy(update={"held": False, "held_by": None, "good": good})
    _lifecycle(ctx, started, "start", "starting", "running")
