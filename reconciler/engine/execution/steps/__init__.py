"""What each kind of step does, by concern: repositories (checkout, remove), dependencies
(apt, pip, build), the app's lifecycle (stage … adopt, and the apps found installed that
the record does not own), and its health (verify). Garbage collection is no step: it
runs after an apply succeeds (engine/execution/collection.py).

An app is a service. A script app runs by its lifecycle scripts, and the unit its
`service` file names says whether it runs: a script's exit code is not trusted (the field's
scripts never use `set -e`), so after `start.sh` the app counts as running only when its
service manager says that unit is active, and after `stop.sh` only as stopped when the
unit is not. A scriptless app's unit is written by lpam and driven through the manager.
Either way, every script and unit runs in `/etc/libpanda.d/apps/<folder>`, the link to the
generation (the AppFolders port, engine/execution/ports.py), where the field's scripts expect it.

Lifecycle steps write their *intent* to the state record before the script runs
(`starting` with the run's id) and the outcome after it (`running`): whatever kills lpam
in between, the next apply knows the app may be active, and — from the exit code the
script's guard leaves behind (reconciler/engine/records/state.py settles it) — whether the
script finished, so a finished script is never run twice and a cut-off one is run again
only once it has certainly ended (the guard holds the apply lock until then).

Each runner takes its own kind of step (schemas/plan.py), validated when the plan was
made or loaded: no argument is parsed here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps.dependencies import apt, build, pip
from reconciler.engine.execution.steps.health import verify
from reconciler.engine.execution.steps.lifecycle import (
    adopt,
    configure,
    install,
    stage,
    start,
    stop,
    uninstall,
)
from reconciler.engine.execution.steps.repositories import (
    check_out,
    checkout,
    record_checkout,
    remove,
)
from schemas.plan import Step, StepKind

Runner = Callable[[Any, Context], None]
"""A runner takes the model of its own kind (the plan's discriminator guarantees it)."""

RUNNERS: dict[StepKind, Runner] = {
    StepKind.CHECKOUT: checkout,
    StepKind.APT: apt,
    StepKind.PIP: pip,
    StepKind.BUILD: build,
    StepKind.REMOVE: remove,
    StepKind.STAGE: stage,
    StepKind.STOP: stop,
    StepKind.UNINSTALL: uninstall,
    StepKind.INSTALL: install,
    StepKind.CONFIGURE: configure,
    StepKind.START: start,
    StepKind.VERIFY: verify,
    StepKind.ADOPT: adopt,
}


def run(step: Step, ctx: Context) -> None:
    """Do one step's work."""
    RUNNERS[step.kind](step, ctx)


__all__ = ["RUNNERS", "check_out", "record_checkout", "run"]
