"""What the app steps share: the generation a step names, as staged on disk (its folder,
its metadata, the place where its scripts run), and the app the record shows installed."""

from __future__ import annotations

from pathlib import Path

from reconciler.base.errors import StepError
from reconciler.base.unit import unit_name
from reconciler.core.planning.model import Generation, app_folder
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.supervision import runtime
from schemas.generation import AppGeneration, GenerationFields
from schemas.record import AppRecord


def known(value: str | None, step: str, name: str) -> str:
    """A value only a plan made offline lacks (such a plan is refused before it runs)."""
    if value is None:
        raise StepError(f"step {step} lacks {name}; the plan is malformed",
                        hint="make a new plan with `lpam plan --out FILE`")
    return value


def staged(app: AppGeneration, step: str, ctx: Context) -> Generation:
    """The generation a step names, as it is staged (its unit is lpam's for a scriptless
    app, named after its folder)."""
    path = known(app.path, step, "path")
    service = unit_name(app_folder(path)) if app.scriptless else app.service
    venv = str(ctx.dependencies().envs.location(tuple(app.pip))) if app.pip else None
    return Generation.model_validate({
        **app.model_dump(exclude={"pip", "user"}), "commit": known(app.commit, step, "commit"),
        "path": path, "tree": known(app.tree, step, "tree"), "service": service, "venv": venv})


def _shared() -> set[str]:
    """What a generation and the record's installed app both say: `GenerationFields` and
    where it came from, without `user` (the record's alone: the metadata never kept it)."""
    return {*GenerationFields.model_fields, "commit", "path", "tree"} - {"user"}


def as_record(gen: Generation, user: str | None) -> AppRecord:
    """The generation as the installed app it becomes (status: installed)."""
    return AppRecord.model_validate({**gen.model_dump(include=_shared()), "user": user})


def on_disk(ctx: Context, app: str, generation: str, fallback: Generation) -> Generation:
    """The generation as its metadata file says, or `fallback` without one."""
    meta = ctx.app_folders().meta(app, generation)
    return meta if meta is not None else fallback


def with_runtime(ctx: Context, gen: Generation) -> Generation:
    """`gen` as a step wants it, with the runtime its staging recorded when the step does
    not say (a rollback's steps come from the state record, which keeps no environment or
    ROS build: the generation's metadata does, so it returns to the build that worked)."""
    meta = ctx.app_folders().meta(gen.name, gen.generation)
    if meta is None or gen.venv is not None or gen.ros_build is not None:
        return gen
    return gen.model_copy(update=meta.model_dump(
        include={"venv", "ros", "ros_build", "ros_workspace", "ros_user"}))


def of_record(ctx: Context, app: AppRecord) -> Generation:
    """The installed app's generation: its metadata, else what the record says."""
    fallback = Generation.model_validate(app.model_dump(include=_shared()))
    return on_disk(ctx, app.name, app.generation, fallback)


def place(ctx: Context, gen: Generation) -> Path:
    """The generation's folder (restored from git first if it went missing), reachable at
    `/etc/libpanda.d/apps/<folder>`: that path, where the field's scripts expect it."""
    folders = ctx.app_folders()
    return folders.point(gen.folder, folders.ensure(gen))


def run_script(ctx: Context, gen: Generation, script: str, params: dict[str, str],
               run: str) -> None:
    """Run one script of `gen` in its place, in its runtime environment."""
    where = place(ctx, gen)
    required = gen.scripts is not None and script in gen.scripts
    ctx.scripts.run(gen.name, where, script, {**params, **runtime(ctx, gen).environment},
                    run=run, required=required)


def installed(app: AppGeneration, step: str, ctx: Context) -> AppRecord:
    """The app the record shows installed, which must be the one the step names."""
    current = ctx.record.installed(app.name)
    if current is None or current.generation != app.generation:
        raise StepError(
            f"step {step}: the state record no longer shows this app installed",
            hint="run `lpam plan` again; the machine changed during the apply",
        )
    return current
