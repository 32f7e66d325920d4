"""An in-memory service manager: the twin of supervisord and systemd in fast tests.

It runs nothing, but keeps the promises the real managers keep (tests/contract/
test_services.py checks both): definitions are installed and removed idempotently, a
started unit is active with a pid that changes when it restarts, stop makes it inactive,
an unknown unit is `known=False` and cannot be started, and a definition no manager can
hold (a line break in an argument or value) is refused at install.

Knobs make the vehicle's bad days reproducible: `crash_on_start` units exit right after
they start (start itself succeeds, as `systemctl start` of a simple service does; the unit
ends "failed" after its `start_limit` restarts), `refuse_start` units make `start` raise,
`known_units` are units created outside lpam (what a script app's `systemctl enable`
leaves), and `output` is what each unit printed. `calls` records every operation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from reconciler.base.errors import ServiceError
from reconciler.base.unit import Unit, UnitState, check_unit_name

FIRST_PID = 4000
OUTSIDE_START_LIMIT = 5  # a unit created outside lpam: the managers' usual start limit


@dataclass
class MemoryServices:
    kind: str = "memory"
    units: dict[str, Unit] = field(default_factory=dict)
    states: dict[str, UnitState] = field(default_factory=dict)
    known_units: set[str] = field(default_factory=set)
    crash_on_start: set[str] = field(default_factory=set)
    refuse_start: set[str] = field(default_factory=set)
    output: dict[str, list[str]] = field(default_factory=dict)
    calls: list[tuple[str, str]] = field(default_factory=list)
    next_pid: int = FIRST_PID

    def check(self, unit: Unit) -> None:
        self.calls.append(("check", _name(unit.name)))
        self._refuse_unwritable(unit)

    def install(self, unit: Unit) -> None:
        name = _name(unit.name)
        self.calls.append(("install", name))
        self._refuse_unwritable(unit)
        self.units[name] = unit  # a running unit keeps running; the new one is for its next start
        self.states.setdefault(name, _stopped(name))

    def _refuse_unwritable(self, unit: Unit) -> None:
        name = _name(unit.name)
        for what, value in [*((f"argument {a!r}", a) for a in unit.argv),
                            *((f"the value of {k}", v) for k, v in unit.environment.items())]:
            if any(c in value for c in "\n\r\x00"):
                raise ServiceError(f"unit {name}: {what} holds a line break or NUL")
        if not unit.argv:
            raise ServiceError(f"unit {name}: no command to run")

    def uninstall(self, name: str) -> None:
        name = _name(name)
        self.calls.append(("uninstall", name))
        self.units.pop(name, None)
        self.states.pop(name, None)
        self.known_units.discard(name)

    def start(self, name: str) -> None:
        name = _name(name)
        self.calls.append(("start", name))
        self._start(name)

    def stop(self, name: str) -> None:
        """A unit this manager does not know is not running under it: nothing to stop."""
        name = _name(name)
        self.calls.append(("stop", name))
        if self._known(name) and self.state(name).running:
            self.states[name] = _stopped(name)

    def restart(self, name: str) -> None:
        name = _name(name)
        self.calls.append(("restart", name))
        if self._known(name) and self.state(name).running:
            self.states[name] = _stopped(name)
        self._start(name)

    def state(self, name: str) -> UnitState:
        try:
            base = check_unit_name(name)
        except ValueError:
            return UnitState(name=name, known=False)
        if not self._known(base):
            return UnitState(name=name, known=False)
        found = self.states.get(base, _stopped(base))
        return UnitState(name=name, known=True, active=found.active, sub=found.sub,
                         restarts=found.restarts, pid=found.pid)

    def logs(self, name: str, lines: int = 20) -> list[str]:
        try:
            base = check_unit_name(name)
        except ValueError:
            return []
        said = self.output.get(base, [])
        return said[-lines:] if lines > 0 else []

    def _start(self, name: str) -> None:
        if not self._known(name):
            raise ServiceError(f"unit {name} is not installed")
        if name in self.refuse_start:
            raise ServiceError(f"unit {name} cannot be started (the twin refuses it)")
        if self.state(name).running:
            return
        if name in self.crash_on_start:
            unit = self.units.get(name)
            limit = unit.start_limit if unit is not None else OUTSIDE_START_LIMIT
            self.next_pid += limit + 1  # each attempt had its process
            self.states[name] = UnitState(name=name, known=True, active="failed", sub="failed",
                                          restarts=limit)
            return
        self.next_pid += 1
        self.states[name] = UnitState(name=name, known=True, active="active", sub="running",
                                      pid=self.next_pid)

    def _known(self, name: str) -> bool:
        return name in self.units or name in self.known_units


def _name(name: str) -> str:
    try:
        return check_unit_name(name)
    except ValueError as exc:
        raise ServiceError(f"unit {name!r}: {exc}") from None


def _stopped(name: str) -> UnitState:
    return UnitState(name=name, known=True, active="inactive", sub="dead")
