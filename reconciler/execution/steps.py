"""What each kind of step does. Every step is idempotent on its own outcome (a checkout
already at its commit, a generation already staged are left alone) and records its
effect in the state record before it returns, so a step interrupted by a power cut is
simply run again and a step that finished is never repeated.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING

from reconciler.adapters.scripts import ScriptRunner
from reconciler.atomic import fsync_dir
from reconciler.errors import StepError
from reconciler.layout import Layout
from reconciler.state import write_record
from schemas.plan import Step, StepKind
from schemas.record import AppRecord, RepositoryRecord, StateRecord

if TYPE_CHECKING:
    from reconciler.adapters.git import GitStore


@dataclass
class Context:
    """Everything a step may touch, passed explicitly."""

    layout: Layout
    store: GitStore
    scripts: ScriptRunner
    record: StateRecord
    clock: Callable[[], datetime]

    def save(self, record: StateRecord) -> None:
        self.record = write_record(self.layout, record)


def _arg(step: Step, name: str) -> str:
    value = step.args.get(name)
    if not isinstance(value, str):
        raise StepError(f"step {step.id} lacks {name}; the plan is malformed")
    return value


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


def stage(step: Step, ctx: Context) -> None:
    """Copy the app folder at its commit into an immutable generation directory."""
    app, generation = _arg(step, "app"), _arg(step, "generation")
    dest = ctx.layout.generation_dir(app, generation)
    if dest.is_dir():
        return
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.parent / f".staging-{generation}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tree = ctx.store.export_folder(
        _arg(step, "repository"), _arg(step, "commit"), _arg(step, "path"), tmp
    )
    if tree != _arg(step, "tree"):
        shutil.rmtree(tmp, ignore_errors=True)
        raise StepError(f"{app}: the app folder's content ({tree[:12]}) is not what was planned")
    os.replace(tmp, dest)
    fsync_dir(dest.parent)


def _installed(step: Step, ctx: Context) -> AppRecord:
    app = ctx.record.app
    if app is None or app.name != _arg(step, "app") or app.generation != _arg(step, "generation"):
        raise StepError(
            f"step {step.id}: the state record no longer shows this app installed",
            hint="run `lpam plan` again; the machine changed during the apply",
        )
    return app


def stop(step: Step, ctx: Context) -> None:
    app = _installed(step, ctx)
    gen_dir = ctx.layout.generation_dir(app.name, app.generation)
    ctx.scripts.run(app.name, gen_dir, "stop.sh", app.params)
    ctx.save(ctx.record.model_copy(update={"app": app.model_copy(update={"running": False})}))


def uninstall(step: Step, ctx: Context) -> None:
    app = _installed(step, ctx)
    gen_dir = ctx.layout.generation_dir(app.name, app.generation)
    if gen_dir.is_dir():
        ctx.scripts.run(app.name, gen_dir, "uninstall.sh", app.params)
    ctx.save(ctx.record.model_copy(update={"app": None}))
    # The generation stays until the apply succeeds: a failed cutover reinstalls it.


def reinstall(previous: AppRecord, ctx: Context) -> None:
    """Put `previous` back after a failed cutover: clean up the half-installed new app,
    then install and start the old generation, recording each effect."""
    current = ctx.record.app
    if current is not None and current != previous:
        gen_dir = ctx.layout.generation_dir(current.name, current.generation)
        if current.running:
            ctx.scripts.run(current.name, gen_dir, "stop.sh", current.params)
        ctx.scripts.run(current.name, gen_dir, "uninstall.sh", current.params)
        ctx.save(ctx.record.model_copy(update={"app": None}))
    if ctx.record.app is None:
        gen_dir = ctx.layout.generation_dir(previous.name, previous.generation)
        ctx.scripts.run(previous.name, gen_dir, "install.sh", previous.params)
        ctx.save(ctx.record.model_copy(update={"app": previous.model_copy(
            update={"running": False})}))
    app = ctx.record.app
    if app is not None and previous.running and not app.running:
        gen_dir = ctx.layout.generation_dir(app.name, app.generation)
        ctx.scripts.run(app.name, gen_dir, "start.sh", app.params)
        ctx.save(ctx.record.model_copy(update={"app": app.model_copy(update={"running": True})}))


def prune_generations(ctx: Context) -> None:
    """After a successful apply, only the installed generation is kept."""
    keep = ctx.record.app
    root = ctx.layout.generations
    if not root.is_dir():
        return
    for app_dir in root.iterdir():
        for gen in app_dir.iterdir() if app_dir.is_dir() else ():
            if keep is None or (app_dir.name, gen.name) != (keep.name, keep.generation):
                shutil.rmtree(gen, ignore_errors=True)


def install(step: Step, ctx: Context) -> None:
    name, generation = _arg(step, "app"), _arg(step, "generation")
    if ctx.record.app is not None:
        raise StepError(
            f"refusing to install {name}: {ctx.record.app.name} is still installed",
            hint="only one app may own the vehicle's CAN hardware; run `lpam plan` again",
        )
    params = step.args.get("params")
    params = params if isinstance(params, dict) else {}
    gen_dir = ctx.layout.generation_dir(name, generation)
    if not gen_dir.is_dir():
        raise StepError(f"{name}: generation {generation} was not staged")
    ctx.scripts.run(name, gen_dir, "install.sh", params)
    record = AppRecord(
        name=name, repository=_arg(step, "repository"), commit=_arg(step, "commit"),
        tree=_arg(step, "tree"), path=_arg(step, "path"), params=params,
        generation=generation, running=False,
    )
    ctx.save(ctx.record.model_copy(update={"app": record}))


def start(step: Step, ctx: Context) -> None:
    app = _installed(step, ctx)
    gen_dir = ctx.layout.generation_dir(app.name, app.generation)
    ctx.scripts.run(app.name, gen_dir, "start.sh", app.params)
    ctx.save(ctx.record.model_copy(update={"app": app.model_copy(update={"running": True})}))


RUNNERS: dict[StepKind, Callable[[Step, Context], None]] = {
    StepKind.CHECKOUT: checkout,
    StepKind.REMOVE: remove,
    StepKind.STAGE: stage,
    StepKind.STOP: stop,
    StepKind.UNINSTALL: uninstall,
    StepKind.INSTALL: install,
    StepKind.START: start,
}
