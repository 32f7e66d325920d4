"""The agent: `lpam sync` passes forever, as a vehicle follows its desired-state repository.

Between passes it waits the configured interval with random jitter (a fleet that booted
together must not fetch together), and after failed passes it waits longer, doubling up to
a cap (a broken server is not hammered; a failed revision is not retried anyway, see
workflow/sync.py). A stop (SIGTERM from systemd at shutdown) is honoured between passes
at once, and during a pass at the next step boundary before a cutover: a cutover that
started always finishes, so the car is never left without its app by a shutdown.
"""

from __future__ import annotations

import random
import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from reconciler.base.layout import Layout
from reconciler.workflow.applying import ApplyOptions
from reconciler.workflow.events import Progress, Report
from reconciler.workflow.machine import Machine
from reconciler.workflow.sync import Synced, sync
from schemas.agent import AgentConfig

# Imported inside functions: each command (sync, agent, install-agent, install-ble) loads only the
# readers and unit writers it uses (~5-15 modules each); a small start-up gain.

JITTER = 0.1  # ± this fraction of the wait
BACKOFF_CAP = 8  # the wait after failures grows to at most this many intervals


def next_wait(interval: float, failures: int, draw: float) -> float:
    """Seconds until the next pass: the interval, doubled per failed pass in a row up to
    `BACKOFF_CAP` intervals, ± `JITTER` by `draw` in [0, 1)."""
    factor: int = min(2 ** max(failures, 0), BACKOFF_CAP)
    return float(interval * factor * (1 - JITTER + 2 * JITTER * draw))


def settings(layout: Layout, file: Path | None) -> AgentConfig:
    """The agent's settings: `file`, else agent.yaml under the root."""
    from reconciler.core.documents import load_agent

    return load_agent(file if file is not None else layout.agent_config)


def one_pass(machine: Machine, config: AgentConfig, *, options: ApplyOptions,
             wait: float | None, report: Report, fetch_only: bool = False,
             bundle: Path | None = None) -> Synced:
    """`lpam sync`: one pass (workflow/sync.py); closed gates are waited for `wait`
    seconds, else as long as the settings say (`gate_wait_seconds`)."""
    return sync(machine, config, report=report, fetch_only=fetch_only, bundle=bundle,
                options=replace(options, wait=config.gate_wait_seconds if wait is None
                                else wait))


@dataclass
class Agent:
    """Runs passes until `stop` is set. `wait` sleeps until a timeout or the stop, and says
    whether the stop came (threading.Event.wait, or a test's clock)."""

    machine: Machine
    config: AgentConfig
    report: Report
    options: ApplyOptions = field(default_factory=ApplyOptions)
    stop: threading.Event = field(default_factory=threading.Event)
    draw: Callable[[], float] = random.random
    passes: list[Synced] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.machine.stop_requested = self.stop.is_set

    @classmethod
    def following(cls, machine: Machine, config: AgentConfig, *, options: ApplyOptions,
                  report: Report) -> Agent:
        """The agent of `lpam agent`: its passes wait for closed gates as its settings say."""
        return cls(machine, config, report=report,
                   options=replace(options, wait=config.gate_wait_seconds,
                                   retry_after=config.interval_seconds))

    def wait(self, seconds: float) -> bool:
        return self.stop.wait(seconds)

    def run(self, *, once: bool = False) -> int:
        """Passes until stopped (exit 0), or one pass (its exit code) when `once`."""
        failures = 0
        # one pass has no next one: a deferral it records names none
        options = replace(self.options, retry_after=None) if once else self.options
        while not self.stop.is_set():
            done = sync(self.machine, self.config, report=self.report, options=options)
            self.passes.append(done)
            if once:
                return done.code
            failures = failures + 1 if done.failed else 0  # a deferral is no failure
            seconds = next_wait(self.config.interval_seconds, failures, self.draw())
            self.report(Progress(f"next pass in {seconds:.0f} s"))
            if self.wait(seconds):
                break
        self.report(Progress("agent stopped"))
        return 0


def install_agent(machine: Machine, command: list[str], *, config_file: Path | None,
                  report: Report) -> tuple[list[str], AgentConfig]:
    """Write the agent's systemd units (adapters/services/agentunits.py); where systemd
    runs, enable and start them. The settings (`config_file`, else agent.yaml) must be
    valid first, so a car is never set to follow a source it cannot read. Returns the unit
    files written and the settings they follow."""
    from reconciler.adapters.services.agentunits import agent_units

    config = settings(machine.layout, config_file)
    other = str(config_file.resolve()) if config_file is not None else None
    return _install_units(machine, agent_units(command, other), report), config


def install_ble(machine: Machine, command: list[str], *, report: Report,
                writes: str = "bonded") -> list[str]:
    """Write the unit of `lpam ble` (adapters/services/agentunits.py), serving in the
    mode `writes` (schemas/bluetooth.py: who may change the car); where systemd runs,
    enable and start it. Returns the unit file written."""
    from reconciler.adapters.services.agentunits import ble_unit
    from schemas.bluetooth import Writes

    return _install_units(machine, ble_unit(command, Writes(writes)), report)


def _install_units(machine: Machine, units: dict[str, str], report: Report) -> list[str]:
    from reconciler.adapters.services.systemd import SystemdServices
    from reconciler.base.atomic import write_atomic
    from reconciler.workflow.events import Note

    written = []
    for name, text in units.items():
        path = machine.layout.systemd_units / f"{name}.service"
        if isinstance(machine.services, SystemdServices):
            machine.services.install_text(name, text, start=True)
        else:
            write_atomic(path, text)
        written.append(str(path))
    if not isinstance(machine.services, SystemdServices):
        report(Note("systemd does not run the apps here: the units were written, not "
                    "enabled (run the command in a terminal instead)"))
    return written
