"""What each kind of step does.

Repository steps are idempotent on their outcome (a checkout already at its commit is left
alone). Lifecycle steps write their *intent* to the state record before the script runs
(`starting` with the run's id) and the outcome after it (`running`): whatever kills lpam in
between, the next apply knows the app may be active, and — from the exit code the
script's guard leaves behind (reconciler/state.py settles it) — whether the script
finished, so a finished script is never run twice and a cut-off one is run again only
once it has certainly ended (the guard holds the apply lock until then).
"""

from __future__ import annotations

import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Literal

from reconciler import generations
from reconciler.errors import StepError
from reconciler.execution.ports import Scripts, Store
from reconciler.generations import Generation
from reconciler.layout import Layout
from reconciler.planning.model import GenerationKey
from reconciler.state import write_record
from schemas.plan import Step, StepKind
from schemas.record import AppRecord, AppStatus, RepositoryRecord, StateRecord, Stray


def new_run() -> str:
    return uuid.uuid4().hex


@dataclass
class Context:
    """Everything a step may touch, passed explicitly."""

    layout: Layout
    store: Store
    scripts: Scripts
    record: StateRecord
    clock: Callable[[], datetime]
    run_id: Callable[[], str] = field(default=new_run)

    def save(self, record: StateRecord) -> None:
        self.record = write_record(self.layout, record)

    def save_app(self, app: AppRecord | None) -> None:
        self.save(self.record.model_copy(update={"app": app}))


def _arg(step: Step, name: str) -> str:
    value = step.args.get(name)
    if not isinstance(value, str):
        raise StepError(f"step {step.id} lacks {name}; the plan is malformed")
    return value


def _params(step: Step) -> dict[str, str]:
    value = step.args.get("params")
    return dict(value) if isinstance(value, dict) else {}


def checkout(step: Step, ctx: Context) -> None:
    key, url, commit = _arg(step, "key"), _arg(step, "url"), _arg(step, "commit")
    if ctx.store.origin_url(key) != url or not ctx.store.has_commit(key, commit):
        ctx.store.fetch(key, url)
    if ctx.store.head(key) != commit:
        ctx.store.checkout(key, commit)
    ref = step.args.get("ref")
    entry = RepositoryRecord(key=key, url=url, ref=ref if isinstance(ref, str) else None,
                             commit=commit)
    others = [r for r in ctx.record.repositories if r.key != key]
    ctx.save(ctx.record.model_copy(update={"repositories": sorted([*others, entry],
                                                                  key=lambda r: r.key)}))


def remove(step: Step, ctx: Context) -> None:
    key = _arg(step, "key")
    if ctx.layout.repository_dir(key).exists():
        ctx.store.remove(key)
    others = [r for r in ctx.record.repositories if r.key != key]
    ctx.save(ctx.record.model_copy(update={"repositories": others}))


def _wanted(step: Step) -> Generation:
    return Generation(
        app=_arg(step, "app"), generation=_arg(step, "generation"),
        repository=_arg(step, "repository"), commit=_arg(step, "commit"),
        path=_arg(step, "path"), tree=_arg(step, "tree"), params=_params(step),
    )


def stage(step: Step, ctx: Context) -> None:
    """Copy the app folder at its commit into an immutable generation directory."""
    generations.stage(ctx.layout, ctx.store, _wanted(step))


def _generation(ctx: Context, app: str, generation: str, fallback: Generation) -> Generation:
    meta = generations.read_meta(ctx.layout.generation_meta(app, generation))
    return meta if meta is not None else fallback


def _run(ctx: Context, gen: Generation, script: str, params: dict[str, str], run: str) -> None:
    """Run one script of `gen`, its folder restored from git first if it went missing."""
    folder: Path = generations.ensure(ctx.layout, ctx.store, gen)
    required = gen.scripts is not None and script in gen.scripts
    ctx.scripts.run(gen.app, folder, script, params, run=run, required=required)


def _installed(step: Step, ctx: Context) -> AppRecord:
    app = ctx.record.app
    if app is None or app.name != _arg(step, "app") or app.generation != _arg(step, "generation"):
        raise StepError(
            f"step {step.id}: the state record no longer shows this app installed",
            hint="run `lpam plan` again; the machine changed during the apply",
        )
    return app


def _lifecycle(ctx: Context, app: AppRecord, script: str, during: AppStatus,
               after: AppStatus | None) -> None:
    """Intent, script, outcome: the record never claims more than is known."""
    run = ctx.run_id()
    ctx.save_app(app.model_copy(update={"status": during, "run": run}))
    fallback = Generation(app=app.name, generation=app.generation, repository=app.repository,
                          commit=app.commit, path=app.path, tree=app.tree, params=app.params)
    _run(ctx, _generation(ctx, app.name, app.generation, fallback), script, app.params, run)
    ctx.save_app(None if after is None else
                 app.model_copy(update={"status": after, "run": None}))


def _stray(step: Step, ctx: Context) -> Stray | None:
    key = (_arg(step, "app"), _arg(step, "generation"))
    return next((s for s in ctx.record.strays if (s.name, s.generation) == key), None)


def _stray_script(ctx: Context, stray: Stray, what: Literal["stop", "uninstall"]) -> None:
    """Like `_lifecycle`, for an app found on disk: intent, script, outcome."""
    def replace(new: Stray | None) -> None:
        strays = [s for s in ctx.record.strays if s.generation != stray.generation
                  or s.name != stray.name]
        ctx.save(ctx.record.model_copy(update={"strays": strays + ([new] if new else [])}))

    run = ctx.run_id()
    replace(stray.model_copy(update={"pending": what, "run": run}))
    fallback = Generation(app=stray.name, generation=stray.generation, params=stray.params)
    gen = _generation(ctx, stray.name, stray.generation, fallback)
    _run(ctx, gen, f"{what}.sh", stray.params, run)
    replace(None if what == "uninstall" else
            stray.model_copy(update={"stopped": True, "pending": None, "run": None}))


def stop(step: Step, ctx: Context) -> None:
    if step.args.get("stray"):
        stray = _stray(step, ctx)
        if stray is not None:
            _stray_script(ctx, stray, "stop")
        return
    _lifecycle(ctx, _installed(step, ctx), "stop.sh", "stopping", "installed")


def uninstall(step: Step, ctx: Context) -> None:
    if step.args.get("stray"):
        stray = _stray(step, ctx)
        if stray is not None:
            _stray_script(ctx, stray, "uninstall")
        return
    # The generation stays until the apply succeeds: a failed cutover reinstalls it.
    _lifecycle(ctx, _installed(step, ctx), "uninstall.sh", "uninstalling", None)


def install(step: Step, ctx: Context) -> None:
    gen = _wanted(step)
    current = ctx.record.app
    redo = (current is not None and (current.name, current.generation) == (gen.app, gen.generation)
            and current.status in ("installing", "uninstalling"))
    if (current is not None and not redo) or ctx.record.strays:
        other = current.name if current is not None else ctx.record.strays[0].name
        raise StepError(
            f"refusing to install {gen.app}: {other} is still installed",
            hint="only one app may own the vehicle's CAN hardware; run `lpam plan` again",
        )
    if not ctx.layout.generation_dir(gen.app, gen.generation).is_dir():
        raise StepError(f"{gen.app}: generation {gen.generation} was not staged")
    app = AppRecord(name=gen.app, repository=gen.repository, commit=gen.commit, tree=gen.tree,
                    path=gen.path, params=gen.params, generation=gen.generation)
    _lifecycle(ctx, app, "install.sh", "installing", "installed")


def start(step: Step, ctx: Context) -> None:
    _lifecycle(ctx, _installed(step, ctx), "start.sh", "starting", "running")


def prune(ctx: Context) -> None:
    """After a successful apply, only generations still installed are kept (the app's and
    any stray's: their scripts are what stops them), and only the exit code still awaited."""
    record = ctx.record
    keep = {GenerationKey.of(s.name, s.generation) for s in record.strays}
    if record.app is not None:
        keep.add(GenerationKey.of(record.app.name, record.app.generation))
    generations.prune(ctx.layout, keep)
    pending = {f"{r}.exit" for r in [record.app.run if record.app else None,
                                      *(s.run for s in record.strays)] if r}
    if ctx.layout.runs.is_dir():
        for result in ctx.layout.runs.iterdir():
            if result.name not in pending:
                result.unlink(missing_ok=True)


RUNNERS: dict[StepKind, Callable[[Step, Context], None]] = {
    StepKind.CHECKOUT: checkout,
    StepKind.REMOVE: remove,
    StepKind.STAGE: stage,
    StepKind.STOP: stop,
    StepKind.UNINSTALL: uninstall,
    StepKind.INSTALL: install,
    StepKind.START: start,
}
