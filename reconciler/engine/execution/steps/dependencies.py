"""Dependency steps, all before the cutover: the app's apt packages, the virtual
environment of its pip requirements, the catkin build of its ROS repositories."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from reconciler.base.errors import DependencyError, GitError
from reconciler.engine.execution.context import Context
from schemas.plan import AptStep, BuildStep, PipStep


def apt(step: AptStep, ctx: Context) -> None:
    """Install the app's apt packages that are still missing, in one batch."""
    packages = ctx.dependencies().packages
    _prepared(step.app, lambda: packages.install(packages.missing(list(step.packages)),
                                                 log=ctx.log))


def pip(step: PipStep, ctx: Context) -> None:
    """The virtual environment of the app's requirements, created and completed."""
    envs = ctx.dependencies().envs
    _prepared(step.app, lambda: envs.ensure(list(step.requirements), log=ctx.log))


def build(step: BuildStep, ctx: Context) -> None:
    """The app's ROS repositories exported at their commits into a build space of their
    own, and built with catkin_make as the ROS user. A space that was built is reused."""
    key = step.build
    workspace = ctx.dependencies().workspace(Path(step.workspace), step.user)
    if workspace.built(key):
        return

    def work() -> None:
        src = workspace.prepare(key)
        for name, commit in sorted(step.ros.items()):
            if not ctx.store.has_commit(step.ros_keys[name], commit):
                ctx.store.fetch(step.ros_keys[name], step.ros_urls[name], want=commit)
            ctx.store.export_folder(step.ros_keys[name], commit, "", src / name)
        workspace.build(key, log=ctx.log)

    _prepared(step.app, work)


def _prepared(app: str, work: Callable[[], object]) -> None:
    """Run a preparation step's work; its errors name the app."""
    try:
        work()
    except (DependencyError, GitError) as exc:
        message = exc.message if exc.message.startswith(app) else f"{app}: {exc.message}"
        raise DependencyError(message, hint=exc.hint, details=exc.details) from None
