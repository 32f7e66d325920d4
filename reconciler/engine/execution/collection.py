"""Garbage collection after an apply succeeds (not a step: nothing of it is planned or
journalled): generations, LPAM's offered folders, environments and ROS builds no kept
generation needs, and the exit codes no record awaits."""

from __future__ import annotations

import getpass
from pathlib import Path

from reconciler.base.layout import KEEP_GENERATIONS
from reconciler.core.planning.model import GenerationKey
from reconciler.engine.execution.context import Context
from schemas.record import history_sets


def prune(ctx: Context, *, keep: int = KEEP_GENERATIONS) -> None:
    """After a successful apply, generations still installed are kept (the app's and any
    stray's: their scripts are what stops them), and the last `keep` good ones of the
    history (what `lpam rollback` returns to: a set of apps);
    and only the exit codes still awaited."""
    record = ctx.record
    kept = {GenerationKey.of(s.name, s.generation) for s in record.strays}
    good = [frozenset(GenerationKey.of(h.app, h.generation) for h in entries)
            for entries in history_sets(record.history) if entries[0].result == "applied"]
    for made in list(dict.fromkeys(reversed(good)))[:keep]:  # the last `keep` good sets
        kept.update(made)
    kept.update(GenerationKey.of(a.name, a.generation) for a in record.apps)
    folders = ctx.app_folders()
    folders.prune(kept)
    folders.keep_offered(record)
    _collect_dependencies(ctx)
    pending = {f"{r}.exit" for r in [*(a.run for a in record.apps),
                                      *(s.run for s in record.strays)] if r}
    if ctx.layout.runs.is_dir():
        for result in ctx.layout.runs.iterdir():
            if result.name not in pending:
                result.unlink(missing_ok=True)


def _collect_dependencies(ctx: Context) -> None:
    """Virtual environments and ROS builds no kept generation runs with are removed; the
    ones kept are what `lpam rollback` returns to without a rebuild."""
    if ctx.deps is None:
        return
    kept = ctx.app_folders().installed()
    ctx.deps.envs.collect({Path(g.venv) for g in kept if g.venv is not None})
    builds: dict[tuple[str, str], set[str]] = {}
    for g in kept:
        if g.ros_workspace is not None and g.ros_build is not None:
            owner = (g.ros_workspace, g.ros_user or getpass.getuser())
            builds.setdefault(owner, set()).add(g.ros_build)
    for (path, user), keys in builds.items():
        ctx.deps.workspace(Path(path), user).collect(keys)
