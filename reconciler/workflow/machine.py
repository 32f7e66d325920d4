"""One lpam installation as every use case sees it: its layout and the ports it acts
through, made once by the caller (the CLI from its flags, the agent from agent.yaml).

Which service manager runs the apps (systemd where it runs, else supervisord; `--services`
or `LPAM_SERVICES` overrides), and how dependencies are prepared (apt, pip environments
made from the system's python3 or `$LPAM_PYTHON`, catkin), are decided here and nowhere
else, so every caller gets the same machine.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.layout import Layout
from reconciler.base.reading import open_append
from reconciler.workflow.events import Output, Report
from schemas.kinds import ServiceKind

if TYPE_CHECKING:
    from reconciler.adapters.git import GitStore
    from reconciler.engine.execution.context import Context
    from reconciler.engine.execution.lock import Lock
    from reconciler.engine.execution.ports import DependencyPorts, Gate, Listener, Services
    from schemas.desired import DesiredState
    from schemas.record import Actor, DesiredRef, StateRecord
    from schemas.timeline import Edge, How, Stamp

# Imported inside functions: each adapter (dulwich, supervisor, packaging, pydantic...) loads
# only when its port is used; every command imports this module (start-up; test_imports.py).


def now() -> datetime:
    return datetime.now(timezone.utc)


def services_for(layout: Layout, override: str | None,
                 env: Mapping[str, str] = os.environ) -> Services:
    """The service manager: `override`, else $LPAM_SERVICES, else systemd where it runs."""
    from reconciler.adapters.services.choice import choose

    return services_named(layout, choose(override=override, env=env))


def services_named(layout: Layout, kind: ServiceKind) -> Services:
    if kind is ServiceKind.SYSTEMD:
        from reconciler.adapters.services.systemd import SystemdServices

        return SystemdServices(layout)
    from reconciler.adapters.services.supervisor import SupervisorServices

    return SupervisorServices(layout)


def dependency_ports(layout: Layout, env: Mapping[str, str] = os.environ) -> DependencyPorts:
    """apt, pip (environments made from $LPAM_PYTHON, default the system's python3) and
    catkin: the ports an app's dependencies are prepared through."""
    from reconciler.adapters.apt import AptPackages
    from reconciler.adapters.catkin import CatkinWorkspace
    from reconciler.adapters.pythonenv import VenvPythonEnvs
    from reconciler.engine.execution.ports import DependencyPorts

    return DependencyPorts(packages=AptPackages(),
                           envs=VenvPythonEnvs(layout.venvs, python=env.get("LPAM_PYTHON")),
                           workspace=CatkinWorkspace)


@dataclass
class Machine:
    """The installation under `layout`, with the ports use cases act through. Ports are made
    when first asked for: a plan of repositories alone, the most frequent command, imports
    neither a service manager's client (supervisord's costs 70 ms) nor apt's, pip's and
    catkin's adapters."""

    layout: Layout
    given_services: Services | None = None
    services_name: ServiceKind = ServiceKind.SUPERVISOR  # the manager `services` makes first
    given_deps: DependencyPorts | None = None
    network_timeout: float = 60.0
    clock: Callable[[], datetime] = field(default=now)
    stop_requested: Callable[[], bool] = field(default=lambda: False)  # the agent's SIGTERM
    # the timeline's clock (None: this boot's id and boottime with `clock`): a test moves
    # the boot and the wall clock through it
    stamp: Callable[[], Stamp] | None = None

    @classmethod
    def at(cls, layout: Layout, *, services: str | None = None,
           network_timeout: float = 60.0) -> Machine:
        from reconciler.adapters.services.choice import choose

        # chosen (and a bad --services refused) now; the client is made when first used
        return cls(layout, services_name=choose(override=services, env=os.environ),
                   network_timeout=network_timeout)

    @property
    def services(self) -> Services:
        if self.given_services is None:
            self.given_services = services_named(self.layout, self.services_name)
        return self.given_services

    @property
    def deps(self) -> DependencyPorts:
        if self.given_deps is None:
            self.given_deps = dependency_ports(self.layout)
        return self.given_deps

    def warm_network(self) -> None:
        """Get the network helper going while the caller still reads its documents: an
        apply or a sync fetches unless every pin is already here (adapters.deadline)."""
        from reconciler.adapters import deadline

        deadline.warm()

    def gate_for(self, desired: DesiredState, base_dir: Path) -> Gate | None:
        """The update gates `desired` declares (None: it declares none, nothing is gated);
        relative paths in it are relative to `base_dir`, its folder."""
        if desired.gates is None:
            return None
        from reconciler.adapters.gate import VehicleGate

        return VehicleGate(desired.gates, desired.vehicle, layout=self.layout,
                           base_dir=base_dir)

    def listener_for(self, desired: DesiredState, base_dir: Path) -> Listener:
        """The vehicle's bus as `desired` names it, for health checks by CAN."""
        from reconciler.adapters.gate import VehicleListener

        return VehicleListener(desired.vehicle, layout=self.layout, base_dir=base_dir)

    def look(self, record: StateRecord | None = None) -> list[Edge]:
        """Write to the timeline what happened to the running apps since the last look (a
        crash, an exit, a power cut, the clock set): before any run changes an app, at
        `lpam status` and at each agent pass. A user who cannot write the timeline (status
        without root) leaves it to the next look."""
        from reconciler.base.errors import LpamError
        from reconciler.engine.execution.provenance import stamp_now, watch
        from reconciler.engine.records.state import read_record

        try:
            return watch(self.layout, record if record is not None else
                         read_record(self.layout), self.services.state,
                         stamp_now(self.stamp, self.clock))
        except (OSError, LpamError):
            return []

    def store(self) -> GitStore:
        from reconciler.adapters.git import GitStore

        return GitStore(self.layout, timeout=self.network_timeout)

    def context(self, store: GitStore, lock: Lock, *, command: str, script_timeout: float,
                report: Report, gate: Gate | None = None, gate_wait: float = 0.0,
                listener: Listener | None = None, resume: str | None = None,
                desired: DesiredRef | None = None,
                retry_after: float | None = None,
                by: Actor | None = None, why: How = "apply") -> tuple[Context, Path]:
        """What the steps of one run may touch, and the log of its scripts and commands."""
        from reconciler.adapters.catkin import find_underlay
        from reconciler.adapters.folders import DiskFolders
        from reconciler.adapters.scripts import ScriptRunner
        from reconciler.engine.execution.context import Context
        from reconciler.engine.records.state import read_record

        started = self.clock().strftime("%Y%m%dT%H%M%SZ")
        log = self.layout.logs / f"{command}-{started}-{os.getpid()}.log"
        record = read_record(self.layout)
        self.look(record)  # what happened since the last look comes before this run's edges
        ctx = Context(
            layout=self.layout, store=store, clock=self.clock,
            record=record, services=self.services,
            scripts=ScriptRunner(root=self.layout.root, log=log, runs=self.layout.runs,
                                 timeout=script_timeout, lock_fd=lock.fd, note=lock.note),
            deps=self.deps, log=CommandLog(log, report), stop_requested=self.stop_requested,
            gate=gate, gate_wait=gate_wait, listener=listener,
            command=resume or f"lpam {command}", desired=desired, underlay=find_underlay,
            folders=DiskFolders(layout=self.layout, store=store), retry_after=retry_after,
            by=by, why=why, stamp=self.stamp,
        )
        return ctx, log


def shutdown_services(layout: Layout) -> bool:
    """`lpam services shutdown`: stop the supervisord lpam started for `layout` (and the
    apps it runs); False when none was running."""
    from reconciler.adapters.services.supervisor import shutdown

    return shutdown(layout)


class CommandLog:
    """The output of a long step (apt, pip, catkin_make): each line appended to the run's
    log, and reported as `Output` for whoever watches."""

    def __init__(self, path: Path, report: Report) -> None:
        self._path = path
        self._report = report

    def __call__(self, line: str) -> None:
        fd = open_append(self._path)
        try:
            os.write(fd, (line + "\n").encode("utf-8", "replace"))
        finally:
            os.close(fd)
        self._report(Output(line))
