"""What every step may touch, passed explicitly: the ports, the record, the clock.

The state record is saved through the context, so that a step's intent and outcome are
on disk (atomically) before and after its work.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from reconciler.base.errors import StateWriteError, StepError
from reconciler.base.layout import Layout
from reconciler.engine.execution.ports import (
    AppFolders,
    DependencyPorts,
    Gate,
    Listener,
    Log,
    Scripts,
    Services,
    Store,
)
from reconciler.engine.execution.provenance import note
from reconciler.engine.records.state import write_record
from schemas.record import Actor, AppRecord, DesiredRef, StateRecord
from schemas.timeline import How, Stamp


@dataclass
class Context:
    """Everything a step may touch, passed explicitly."""

    layout: Layout
    store: Store
    scripts: Scripts
    services: Services
    record: StateRecord
    clock: Callable[[], datetime]
    run_id: Callable[[], str] = field(default=lambda: uuid.uuid4().hex)
    monotonic: Callable[[], float] = time.monotonic
    sleep: Callable[[float], None] = time.sleep
    deps: DependencyPorts | None = None
    log: Log = field(default=lambda line: None)  # long steps' output: the apply log
    stop_requested: Callable[[], bool] = field(default=lambda: False)
    gate: Gate | None = None  # None: the cutover is not gated (no `gates:`, or --force)
    gate_wait: float = 0.0  # seconds the cutover may wait for closed gates to open
    listener: Listener | None = None  # the vehicle's bus, for `health.can`
    command: str = "lpam apply"  # what a user runs to resume this one (said in errors)
    desired: DesiredRef | None = None  # what this apply works toward (holds hold against it)
    # Seconds until the agent's next pass tries a deferred apply again (None: nothing
    # tries it again by itself; the next `lpam apply` does).
    retry_after: float | None = None
    # The ROS distribution's setup file a launch app without a build of its own runs inside
    # (None: roslaunch is on PATH already); the caller that chooses adapters gives the probe.
    underlay: Callable[[], Path | None] = field(default=lambda: None)
    # The generation folders and LPAM's app folders. No default: the disk implementation is
    # an adapter (adapters/folders.py), which the engine never names; the caller that
    # chooses adapters gives it.
    folders: AppFolders | None = None
    by: Actor | None = None  # who asked for this run: on the history and last apply it writes
    # Why apps begin and end in this run, as the timeline says it (an automatic rollback
    # sets "rollback" for its own steps: engine/execution/recovery.py).
    why: How = "apply"
    # Now as the timeline stamps it (None: this boot's id and boottime with `clock`):
    # tests move the boot and the wall clock through it.
    stamp: Callable[[], Stamp] | None = None

    def dependencies(self) -> DependencyPorts:
        if self.deps is None:  # a caller that plans dependencies must give their ports
            raise StepError("this apply cannot prepare dependencies (no ports given); this "
                            "is a bug in lpam")
        return self.deps

    def app_folders(self) -> AppFolders:
        if self.folders is None:  # every caller that runs app steps must give the port
            raise StepError("this apply cannot touch app folders (no port given); this is "
                            "a bug in lpam")
        return self.folders

    def save(self, record: StateRecord) -> None:
        """Write `record` (a step's intent before its work, its outcome after). Failing,
        nothing is done that it would have recorded: StateWriteError."""
        before = self.record
        try:
            note(self, before, record)  # what began and ended, before the record says so
            self.record = write_record(self.layout, record)
        except OSError as exc:
            raise StateWriteError(
                f"cannot write the state record: {exc.strerror or exc}",
                path=self.layout.state_record) from None

    def save_app(self, name: str, app: AppRecord | None) -> None:
        """Write the installed app `name` as `app` (None: it is uninstalled)."""
        self.save(self.record.with_app(name, app))
