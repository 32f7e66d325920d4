"""Watching the app's unit through the service manager: the unit lpam writes for a
scriptless app, waiting (bounded) for a unit to come up or go down after its script or
start, the settle of the health check, and the unit's last output for error messages.

A script's exit code is not trusted (the field's scripts never use `set -e`): these
answers are what lpam records. A unit this manager cannot know (a systemd unit asked of
supervisord) leaves the scripts' word standing, shown as unverified.
"""

from __future__ import annotations

import getpass
from dataclasses import dataclass, field
from pathlib import Path

from reconciler.base.errors import HealthError, ServiceError, StepError
from reconciler.base.unit import Unit, UnitState, unit_name
from reconciler.core.planning.model import Generation, app_folder
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.ports import DEFAULT_PATH, SOURCE_THEN_EXEC
from reconciler.engine.execution.provenance import provenance_environment
from schemas.record import AppRecord

SETTLE_POLL = 0.25  # seconds between looks at a unit while it settles
UNIT_WAIT = 10.0  # how long a unit may take to become (in)active after its script ended
LOG_LINES = 20


@dataclass(frozen=True)
class Runtime:
    """What a generation runs inside besides its folder: the virtual environment of its pip
    requirements (its `bin` first on PATH) and the setup file of its ROS build."""

    environment: dict[str, str] = field(default_factory=dict)
    ros_setup: Path | None = None


def runtime(ctx: Context, gen: Generation) -> Runtime:
    env: dict[str, str] = {}
    if gen.venv is not None:
        env["VIRTUAL_ENV"] = gen.venv
        env["PATH"] = f"{gen.venv}/bin:{DEFAULT_PATH}"
    setup = None
    if gen.ros_build is not None and gen.ros_workspace is not None:
        workspace = ctx.dependencies().workspace(Path(gen.ros_workspace),
                                                 gen.ros_user or getpass.getuser())
        setup = workspace.setup_script(gen.ros_build)
        env["LPAM_ROS_SETUP"] = str(setup)
        # roslaunch keeps its logs in $ROS_HOME: the ROS user's ~/.ros, beside the workspace
        env["ROS_HOME"] = str(Path(gen.ros_workspace).parent / ".ros")
    elif gen.launch is not None:
        # no build of its own: roslaunch comes from the ROS distribution, whose setup puts
        # it on PATH (/opt/ros/noetic/bin on the Pi; Debian's own is in /usr/bin already)
        setup = ctx.underlay()
    return Runtime(env, setup)


ROS_WRAPPER = SOURCE_THEN_EXEC  # a launch app's roslaunch, inside its build's devel space


def unit_for(ctx: Context, app: AppRecord, place: Path, run: Runtime | None = None) -> Unit:
    """The unit of a scriptless app: its program found in its folder or on PATH (inside its
    ROS build's environment when it has one: roslaunch needs it), its parameters and
    runtime as its environment, run as its user (no switch when that is lpam's own)."""
    run = run or Runtime()
    if app.command is not None:
        argv = list(app.command)
        if "/" in argv[0] or (place / argv[0]).is_file():
            argv[0] = str(place / argv[0])
    else:
        assert app.launch is not None
        package, launch_file = app.launch.split("/", 1)
        argv = ["roslaunch", package, launch_file]
    if run.ros_setup is not None:
        argv = ["bash", "-c", ROS_WRAPPER, "lpam-ros", str(run.ros_setup), *argv]
    env = dict(app.params)
    env.update(run.environment)
    env.update(LPAM_ROOT=str(ctx.layout.root), LPAM_APP=app.name, LPAM_APP_DIR=str(place))
    env.update(provenance_environment(ctx, app))
    user = None if app.user in (None, getpass.getuser()) else app.user
    folder = app_folder(app.path)
    return Unit(name=unit_name(folder), argv=tuple(argv), directory=place, environment=env,
                user=user, description=f"lpam app {app.name} ({app.generation})",
                log=ctx.layout.app_logs / f"{folder}.log")


def await_unit(ctx: Context, app: str, unit: str, *, active: bool, script: str | None) -> UnitState:
    """Wait (bounded) until the service manager reports `unit` (in)active. A unit this
    manager cannot know leaves the scripts' word standing: the state shows unverified."""
    deadline = ctx.monotonic() + UNIT_WAIT
    while True:
        state = ctx.services.state(unit)
        if not state.known or state.running == active:
            return state
        if ctx.monotonic() >= deadline:
            break
        ctx.sleep(SETTLE_POLL)
    if not active:
        raise StepError(
            f"{app}: {script or 'the stop'} ended but unit {unit} is still active after "
            f"{UNIT_WAIT:g} s", details=log_tail(ctx, unit),
            hint="the unit must stop before another app may have the CAN bus; see `lpam "
            "logs` and fix the app's stop.sh",
        )
    # An app that does not come up is a failed health check: the apply rolls back.
    now = state.describe().removeprefix(f"unit {unit} ")
    raise HealthError(
        f"{app}: {script + ' exited 0 but ' if script else ''}unit {unit} is {now}, not "
        f"active, {UNIT_WAIT:g} s after it was started", details=log_tail(ctx, unit),
        hint="see the app's output above; the unit named in the app's `service` file must "
        "run once start.sh ends" if script else "see the app's output above: it exits "
        "right after it starts",
    )


def log_tail(ctx: Context, unit: str | None) -> list[str]:
    """The unit's last lines of output, for the error that explains its failure; logs
    are a courtesy there, so the service manager failing to give them (ServiceError, or a
    log file that cannot be read) is not an error of its own. Anything else is a bug in
    lpam and raises: it must not pass for an app with no output."""
    if unit is None:
        return []
    try:
        lines = ctx.services.logs(unit, LOG_LINES)
    except (ServiceError, OSError):
        return []
    return [f"{unit}: {line}" for line in lines[-LOG_LINES:]]


def settle(ctx: Context, app: AppRecord, unit: str, seconds: float) -> None:
    first = ctx.services.state(unit)
    if not first.known:
        return  # unverifiable here (a systemd unit under supervisord): the scripts' word
    deadline = ctx.monotonic() + seconds
    state = first
    while True:
        problem = None
        if not state.running:
            problem = f"{state.describe()}"
        elif state.pid != first.pid:
            problem = f"unit {unit} restarted (pid {first.pid} → {state.pid})"
        elif state.restarts > first.restarts:
            times = state.restarts - first.restarts
            problem = f"unit {unit} restarted {times} time{'' if times == 1 else 's'}"
        if problem is not None:
            raise HealthError(
                f"{app.name} did not stay up for {seconds:g} s after it started: {problem}",
                hint="fix the app and apply again", details=log_tail(ctx, unit))
        if ctx.monotonic() >= deadline:
            return
        ctx.sleep(min(SETTLE_POLL, max(deadline - ctx.monotonic(), 0)))
        state = ctx.services.state(unit)
