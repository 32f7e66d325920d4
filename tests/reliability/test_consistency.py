"""What lpam says agrees with itself and with the car (issue 30, "What to build" 3).

Over random cars of several apps, random sequences of commands — `lpam apply` of random
sets of apps and parameters (from the default file or `-f` relative to the directory it
was typed in), `lpam stop|start [APP]`, `lpam rollback`, `lpam apply --release`, running
a command lpam suggested — each perhaps deferred by closed update gates, killed
(SIGKILL: lpam dies) or interrupted (Ctrl-C) at a random instant, or failing a script;
and stops of an app's unit by its service manager from outside lpam — after every
command, and at a random instant inside one, the checks of tests/consistency.py:

(a) the report (the StatusReport as `lpam status --json` prints it, and the table) never
    says "in progress" and "cut off" together;
(b) `lpam plan` proposes nothing ⇔ the report shows nothing pending except holds, which
    it names (and then the plan does not say the machine matches the desired state);
(c) every app the report calls running is running by the service manager's word, or is
    marked unverified where it is shown, and no column says otherwise;
(d) every command lpam suggests (resume hints, how a hold ends, import hints) runs as
    printed from another directory.

Two layers. The fast one runs the real `lpam` (reconciler/frontends/cli.py `main`) in
this process, on a temporary `--root`, with the ports the in-memory twins of
tests/unit/test_convergence.py (a store, scripts, a service manager, update gates): the
planner, executor, record, report and every text are the real ones. A kill is the twins'
`Crash` (lpam dies where it stands; its flock goes with it), an interrupt a
KeyboardInterrupt raised where a script runs. `LPAM_CONSISTENCY_EXAMPLES` (default 500;
LPAM_LONG=1: 5,000) random sequences. The real one runs the CLI in subprocesses under a
real supervisord with a loopback git daemon (tests/integration/several.py's car), with
real signals, `LPAM_CONSISTENCY_ROUNDS` rounds (default 4; LPAM_LONG=1: 40).

Violations are collected per sequence and reported all at once, with the commands that
led there, so that each is a reproduction.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import shlex
import signal
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from unittest import mock

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import Crash, MemoryGate, MemoryScripts, MemoryStore
from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.layout import Layout
from reconciler.engine.execution.context import Context
from reconciler.engine.records.state import read_record
from reconciler.frontends import cli
from reconciler.frontends.console import Calling
from reconciler.workflow.machine import Machine
from tests.consistency import (
    Hint,
    both_in_progress_and_cut_off,
    failed_as_printed,
    hint_as_printed,
    hints,
    last_apply_as_it_ended,
    plan_agrees,
    proposed,
    running_is_true,
)
from tests.integration.several import car_url, lpam
from tests.lengths import knob

__all__ = ["car_url", "lpam"]  # fixtures of the real layer

EXAMPLES = knob("LPAM_CONSISTENCY_EXAMPLES", 500, 5000)  # docs/reliability.md
COLLECT = os.environ.get("LPAM_CONSISTENCY_COLLECT", "")
"""A file: each violation is appended there (one JSON line: what, and the commands that
led to it) and the test passes — a survey of what is open, never the CI's setting."""
URL = "git://h/apps"
C1, C2 = "a" * 40, "b" * 40
APPS = ("x", "y", "z")  # x and y have scripts; z is scriptless (lpam writes its unit)
SCRIPTS = ("install.sh", "uninstall.sh", "start.sh", "stop.sh")
UNIT = "lpam-app-z"
CATALOG = """\
apps:
  - name: x
    description: an app with scripts
    health: {settle_seconds: 0}
  - name: y
    description: another app with scripts
    health: {settle_seconds: 0}
  - name: z
    description: an app lpam runs as a unit
    command: [python3, run.py]
    health: {settle_seconds: 0}
"""


def remote() -> dict[str, dict[str, dict[str, tuple[str, dict[str, str]]]]]:
    commits: dict[str, dict[str, tuple[str, dict[str, str]]]] = {}
    for n, commit in enumerate((C1, C2)):
        folders: dict[str, tuple[str, dict[str, str]]] = {
            "": (f"{n}0" * 20, {"libpanda-apps.yaml": CATALOG})}
        for i, app in enumerate(APPS):
            files = {"run.py": f"# {commit}\n"} if app == "z" else \
                {s: f"# {commit}\n" for s in SCRIPTS}
            folders[app] = (f"{n}{i + 1}" * 20, files)
        commits[commit] = folders
    return {URL: commits}


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, raised where lpam stands (in a script, as the terminal's SIGINT would)."""


@dataclass
class Mishap:
    """What befalls one command: at the `at`-th script or unit operation, `kind` — `kill`
    (SIGKILL: `when` before, during or after it), `interrupt` (Ctrl-C), `fail` (it exits
    1), `look` (a `lpam status` beside it, in another terminal). `gate`: the update gates
    are closed for the whole command."""

    kind: str | None = None
    at: int = 0
    when: str = "during"
    gate: bool = False


class Vehicle(MemoryScripts):
    """The scripts' twin with the mishaps of tests/unit/test_convergence.py, and a hook
    run beside a chosen operation (the `lpam status` of another terminal)."""

    def __init__(self, runs_dir: Path) -> None:
        super().__init__(runs_dir=runs_dir)
        self.count = 0
        self.mishap = Mishap()
        self.beside: Callable[[], None] = lambda: None
        self.crash = self.hit

    def hit(self, call: str) -> str | None:
        """Count an operation; what befalls it."""
        self.count += 1
        mishap = self.mishap
        if self.count != mishap.at + 1 or mishap.kind is None:
            return None
        if mishap.kind == "kill":
            return mishap.when
        if mishap.kind == "interrupt":
            raise Interrupted
        if mishap.kind == "fail":
            self.fail.add(call)
        if mishap.kind == "look":
            self.beside()
        return None

    def _effect(self, app: str, script: str) -> None:
        saved = list(self.violations)
        super()._effect(app, script)  # several apps share nothing here: no one-app rule
        self.violations = saved


class Services(MemoryServices):
    """The service manager's twin, whose operations befall the same mishaps as scripts."""

    def __init__(self, vehicle: Vehicle) -> None:
        super().__init__()
        self.vehicle = vehicle

    def _through(self, op: str, name: str, work: Callable[[], None]) -> None:
        when = self.vehicle.hit(f"z:{op}")
        if when == "before":
            raise Crash(op)
        work()
        if when in ("during", "after"):
            raise Crash(op)
        if f"z:{op}" in self.vehicle.fail:
            self.vehicle.fail.discard(f"z:{op}")
            from reconciler.base.errors import ServiceError

            raise ServiceError(f"{name}: {op} failed")

    def start(self, name: str) -> None:
        self._through("start", name, lambda: MemoryServices.start(self, name))

    def stop(self, name: str) -> None:
        self._through("stop", name, lambda: MemoryServices.stop(self, name))

    def outside_stop(self) -> None:
        """The manager stops the unit on its own (an operator's `supervisorctl stop`, an
        OOM kill): lpam is not asked."""
        if self.state(UNIT).running:
            MemoryServices.stop(self, UNIT)


@dataclass
class TwinMachine(Machine):
    """The machine of the CLI, its ports the world's twins."""

    world: Any = field(default=None)

    def store(self) -> Any:
        return self.world.store

    def gate_for(self, desired: Any, base_dir: Path) -> Any:
        return MemoryGate(["moving: 30.0 km/h"]) if self.world.vehicle.mishap.gate else None

    def listener_for(self, desired: Any, base_dir: Path) -> Any:
        return None

    def warm_network(self) -> None:
        return None

    def context(self, store: Any, lock: Any, *, command: str, script_timeout: float,
                report: Any, gate: Any = None, gate_wait: float = 0.0, listener: Any = None,
                resume: str | None = None, desired: Any = None,
                retry_after: float | None = None, by: Any = None,
                why: Any = "apply") -> tuple[Context, Path]:
        log = self.layout.logs / f"{command}.log"
        ctx = Context(layout=self.layout, store=store, clock=self.clock,
                      record=read_record(self.layout), services=self.services,
                      scripts=self.world.vehicle, sleep=lambda s: None,
                      monotonic=self.world.tick, gate=gate, gate_wait=gate_wait,
                      command=resume or f"lpam {command}", desired=desired,
                      folders=DiskFolders(layout=self.layout, store=store),
                      retry_after=retry_after, by=by, why=why)
        return ctx, log


@dataclass
class Said:
    """One command as a user saw it."""

    argv: list[str]
    code: int | str
    out: str
    err: str
    began: bool = True  # it changed the record's last apply: the report speaks of it


@dataclass
class World:
    """A car on a temporary root, told what to do by the real CLI in this process."""

    base: Path
    clock: float = 0.0
    violations: list[str] = field(default_factory=list)
    history: list[str] = field(default_factory=list)
    last_hints: list[Hint] = field(default_factory=list)
    found: list[tuple[str, str]] = field(default_factory=list)  # (what, after which commands)
    wished: Path | None = None  # the desired state the last apply was given

    def __post_init__(self) -> None:
        self.root = self.base / "root"
        self.layout = Layout(self.root)
        self.store = MemoryStore(layout=self.layout, remotes=remote())
        self.vehicle = Vehicle(self.layout.runs)
        self.services = Services(self.vehicle)
        self.machine = TwinMachine(self.layout, given_services=self.services, world=self)
        self.elsewhere = self.base / "elsewhere"
        self.elsewhere.mkdir()
        self.typed = self.base / "typed"  # where the operator types a relative -f
        self.typed.mkdir()

    def tick(self) -> float:
        self.clock += 0.5
        return self.clock

    @contextlib.contextmanager
    def twins(self) -> Iterator[None]:
        def services_for(layout: Layout, override: str | None, env: Any = None) -> Any:
            return self.services

        with mock.patch.object(Machine, "at", lambda *a, **k: self.machine), \
                mock.patch("reconciler.workflow.machine.services_for", services_for), \
                mock.patch("reconciler.adapters.git.GitStore",
                           lambda layout, **k: self.store):
            yield

    def lpam(self, *args: str, cwd: Path | None = None, mishap: Mishap | None = None,
             root: bool = True) -> Said:
        """One `lpam --root ROOT ARGS` typed in `cwd`."""
        argv = (["--root", str(self.root)] if root else []) + list(args)
        self.vehicle.mishap = mishap or Mishap()
        self.vehicle.count = 0
        out, err = io.StringIO(), io.StringIO()
        before = last_apply(self.root)
        here = os.getcwd()
        handler = signal.getsignal(signal.SIGTERM)
        os.chdir(cwd or self.elsewhere)
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    code: int | str = cli.main(argv)
                except Crash:
                    code = "killed"
                except SystemExit as exc:  # argparse
                    code = exc.code if isinstance(exc.code, int) else 2
        finally:
            os.chdir(here)
            signal.signal(signal.SIGTERM, handler)
            self.vehicle.mishap = Mishap()
            self.vehicle.fail.clear()
        return Said(["lpam", *argv], code, out.getvalue(), err.getvalue(),
                    began=last_apply(self.root) != before)

    def look(self, when: str) -> tuple[dict[str, Any], str]:
        """`lpam status --json` and `lpam status`, checked by (a) and (c)."""
        shown = self.lpam("status", "--json")
        table = self.lpam("status")
        for said in (shown, table):
            if said.code != 0 or "Traceback" in said.err:
                self.violations.append(f"{when}: `lpam status` exit {said.code}: {said.err}")
        try:
            report = json.loads(shown.out)
        except ValueError:
            self.violations.append(f"{when}: `lpam status --json` is not JSON: {shown.out}")
            return {}, table.out
        found = both_in_progress_and_cut_off(report, table.out)
        found += running_is_true(report, table.out, self.manager_runs(report))
        self.note(when, found)
        return report, table.out

    def manager_runs(self, report: dict[str, Any]) -> dict[str, bool | None]:
        runs: dict[str, bool | None] = {}
        for app in report.get("installed") or []:
            unit = app.get("unit")
            state = None if unit is None else self.services.state(unit["name"])
            runs[app["name"]] = None if state is None or not state.known else state.running
        return runs

    def note(self, when: str, found: list[str]) -> None:
        for what in found:
            self.found.append((what.replace(str(self.base), "BASE"), when))
            if f"{when}: {what}" not in self.violations:
                self.violations.append(f"{when}: {what}")

    def check(self, when: str, said: Said | None) -> None:
        """After a command: (a), (b), (c) on the report and the plan, (d) on every
        command suggested by it, the status or the plan."""
        report, table = self.look(when)
        texts = [("status", table), ("status --json", json.dumps(report))]
        if said is not None:
            texts += [(shlex.join(said.argv[3:]), said.out + said.err)]
        if said is not None and said.began:
            self.note(when, last_apply_as_it_ended(report, table, applied(said),
                                                   said.code))
        if self.wished is not None:  # else nothing was ever to be applied: no plan
            steps, text = self.plan(when)
            self.note(when, plan_agrees(report, table, steps, text))
            texts += [("plan", text)]
        self.last_hints = hints(texts)
        for hint in self.last_hints:
            self.note(when, hint_as_printed(hint, self.root))

    def plan(self, when: str) -> tuple[list[str], str]:
        """`lpam plan` of the desired state last given to an apply: its steps, and its
        text as `lpam plan` prints it (its notes included)."""
        from reconciler.core.planning.render import render
        from schemas.plan import Plan

        plan = self.lpam("plan", "--json", "-f", str(self.wished))
        if plan.code != 0:
            self.note(when, [f"`lpam plan` exit {plan.code}: {plan.err.strip()}"])
            return [], plan.err
        made = Plan.model_validate_json(plan.out)
        # the plan as `lpam plan` prints it: its suggestions spelled for this root
        text = Calling.of(self.root).spell(render(made))
        return proposed(made), text + "\n" + plan.err

    def follow(self, index: int) -> Said | None:
        """Run a suggested command as printed, from another directory (only one that names
        this root: one that does not is a violation already, and would act on /)."""
        usable = [h for h in self.last_hints if h.argv and "--root" in h.argv
                  and str(self.root) in h.argv]
        if not usable:
            return None
        hint = usable[index % len(usable)]
        argv = hint.argv or []
        with mock.patch("sys.stdin.isatty", lambda: True), \
                mock.patch("builtins.input", lambda question="": "yes"):  # a terminal
            said = self.lpam(*argv[1:], root=False, cwd=self.elsewhere)
        wished = applies(argv, self.root)
        if wished is not None and wished.exists():  # what the plan is compared with now
            self.wished = wished
        self.note(f"running `{hint.text}`", failed_as_printed(hint, int(said.code)
                                                             if isinstance(said.code, int)
                                                             else 0, said.err))
        return said


def last_apply(root: Path) -> object:
    """The record's last apply now (read as lpam reads it)."""
    return read_record(Layout(root)).last_apply


def applies(argv: list[str], root: Path) -> Path | None:
    """The desired state a suggested `lpam … apply [-f FILE]` applies (None: not an apply,
    or a file that is not there from where it ran)."""
    args = argv[1:]
    while args[:1] == ["--root"]:
        args = args[2:]
    if args[:1] != ["apply"]:
        return None
    if "-f" in args[:-1]:
        given = Path(args[args.index("-f") + 1])
        return given if given.is_absolute() and given.exists() else None
    return Layout(root).desired_state


def applied(said: Said) -> str:
    """The command of `said` (`apply`, `stop`…), past lpam's global options."""
    args = said.argv[1:]
    while args and args[0] == "--root":
        args = args[2:]
    return args[0] if args else ""


def desired(wish: tuple[tuple[str, int], ...]) -> str:
    """A desired state (version 2) of these apps, each with its parameter."""
    lines = ["version: 2", "repositories:", f"  - url: {URL}", f"    ref: {C1}", "apps:"]
    for app, mode in wish:
        lines += [f"  - name: {app}", f"    params: {{MODE: \"{mode}\"}}"]
    if not wish:
        lines[-1] = "apps: []"
    return "\n".join(lines) + "\n"


wishes = st.lists(st.tuples(st.sampled_from(APPS), st.integers(0, 1)), max_size=3,
                  unique_by=lambda t: t[0]).map(tuple)
mishaps = st.one_of(
    st.just(Mishap()),
    st.builds(Mishap, kind=st.sampled_from(["kill", "interrupt", "fail", "look"]),
              at=st.integers(0, 8), when=st.sampled_from(["before", "during", "after"])),
    st.just(Mishap(gate=True)),
)
commands = st.one_of(
    st.tuples(st.just("apply"), wishes, st.booleans(), mishaps),
    st.tuples(st.just("stop"), st.sampled_from((None, *APPS)), mishaps),
    st.tuples(st.just("start"), st.sampled_from((None, *APPS)), mishaps),
    st.tuples(st.just("rollback"), mishaps),
    st.tuples(st.just("release"), mishaps),
    st.tuples(st.just("outside")),
    st.tuples(st.just("import")),
    st.tuples(st.just("hint"), st.integers(0, 5)),
)


def play(world: World, command: tuple[Any, ...]) -> None:
    """One command of a sequence, then the checks."""
    kind = command[0]
    said: Said | None = None
    mishap: Mishap = command[-1] if isinstance(command[-1], Mishap) else Mishap()
    if mishap.kind == "look":
        def beside() -> None:
            world.look(f"{' ; '.join(world.history)} ; {command[0]} (status beside it)")

        world.vehicle.beside = beside
    if kind == "apply":
        _, wish, relative, _ = command
        if relative:
            (world.typed / "wish.yaml").write_text(desired(wish))
            world.wished = world.typed / "wish.yaml"
            said = world.lpam("apply", "--yes", "-f", "wish.yaml", cwd=world.typed,
                              mishap=mishap)
        else:
            world.layout.desired_state.parent.mkdir(parents=True, exist_ok=True)
            world.layout.desired_state.write_text(desired(wish))
            world.wished = world.layout.desired_state
            said = world.lpam("apply", "--yes", mishap=mishap)
    elif kind in ("stop", "start"):
        said = world.lpam(kind, *([command[1]] if command[1] else []), mishap=mishap)
    elif kind == "rollback":
        said = world.lpam("rollback", "--yes", mishap=mishap)
    elif kind == "release":
        if world.layout.desired_state.exists():  # what `apply --release` applies
            world.wished = world.layout.desired_state
        said = world.lpam("apply", "--yes", "--release", mishap=mishap)
    elif kind == "outside":
        world.services.outside_stop()
    elif kind == "import":
        said = world.lpam("import-lpam", str(lpam_etc(world.base)), "-o",
                          f"imported-{len(world.history)}.yaml", cwd=world.typed)
    elif kind == "hint":
        said = world.follow(command[1])
    shown = kind if said is None else f"{shlex.join(said.argv[3:])} → {said.code}"
    world.history.append(f"{shown} [{mishap_said(mishap)}]")
    if said is not None and ("Traceback" in said.err or "internal error" in said.err):
        world.note(world.history[-1], [f"a traceback or internal error: {said.err}"])
    world.check(" ; ".join(world.history), said)


def lpam_etc(base: Path) -> Path:
    """/etc/libpanda.d as LPAM left it on a car it ran (tests/integration/test_takeover.py),
    outside the root: `lpam import-lpam` reads it and writes a desired state."""
    etc = base / "libpanda.d"
    if not etc.exists():
        clone = etc / "apps-repositories/lab/apps/.git"
        (clone / "refs/heads").mkdir(parents=True)
        (clone / "HEAD").write_text("ref: refs/heads/main\n")
        (clone / "refs/heads/main").write_text(C1 + "\n")
        (etc / "apps/x").mkdir(parents=True)
        (etc / "app-manifest.yaml").write_text(
            "version: 0.0\nrepositories:\n  lab/apps: {branch: main}\ncurrent: x\n")
    return etc


def mishap_said(mishap: Mishap) -> str:
    if mishap.gate:
        return "gates closed"
    if mishap.kind is None:
        return "-"
    return f"{mishap.kind} at operation {mishap.at}" + \
        (f" ({mishap.when})" if mishap.kind == "kill" else "")


def run_sequence(base: Path, sequence: list[tuple[Any, ...]]) -> World:
    world = World(base)
    with world.twins():
        for command in sequence:
            play(world, command)
    return world


@settings(max_examples=EXAMPLES, deadline=None, database=None,
          derandomize=EXAMPLES <= 500,  # CI's length replays one set; longer runs explore
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(commands, min_size=1, max_size=7))
# found by a 5,000-example run: an apply killed before its last start, then `lpam stop`
# (or `lpam start`): the report owed "goes on from where it stood", the plan said nothing
@example([("apply", (("x", 0), ("y", 0), ("z", 0)), False, Mishap("kill", 4, "before")),
          ("stop", None, Mishap())])
@example([("apply", (("x", 0), ("y", 0), ("z", 0)), False, Mishap("kill", 4, "before")),
          ("start", None, Mishap())])
def test_what_lpam_says_agrees_with_itself_and_with_the_car(
        sequence: list[tuple[Any, ...]]) -> None:
    with tempfile.TemporaryDirectory() as base:
        world = run_sequence(Path(base), sequence)
        if COLLECT:
            with open(COLLECT, "a", encoding="utf-8") as out:
                for what, when in world.found:
                    out.write(json.dumps({"what": what, "after": when}) + "\n")
            return
        assert world.violations == [], "\n".join(world.violations)


# --- the real layer: subprocesses, supervisord, a loopback git daemon ---------------------

ROUNDS = knob("LPAM_CONSISTENCY_ROUNDS", 4, 40)  # LPAM_LONG=1: 40 (docs/reliability.md)
SEED = int(os.environ.get("LPAM_CONSISTENCY_SEED", "30"))
SETS = (("ctl-a", "recorder"), ("ctl-b", "recorder", "tracker"), ("ctl-a",),
        ("recorder", "tracker"), ("ctl-b", "tracker"))
REAL_COMMANDS = ("apply", "apply -f", "stop", "stop APP", "start", "start APP", "rollback",
                 "release", "gated", "services shutdown", "kill -9 supervisord")
FAULTS = (None, None, "SIGKILL", "SIGINT", "SIGTERM", "look")
GATES = "gates: {stationary_seconds: 30}\n"


@dataclass
class RealCar:
    """The real `lpam` on a root with a real supervisord; what it says, checked."""

    lpam: Any  # tests.integration.apps.Lpam
    base: Path
    violations: list[str] = field(default_factory=list)
    history: list[str] = field(default_factory=list)
    wished: Path | None = None
    last_hints: list[Hint] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.elsewhere = self.base / "elsewhere"
        self.typed = self.base / "typed"
        for folder in (self.elsewhere, self.typed):
            folder.mkdir(parents=True, exist_ok=True)

    @property
    def root(self) -> Path:
        return Path(self.lpam.root)

    def argv(self, *args: str) -> list[str]:
        import sys

        return [sys.executable, "-m", "reconciler", "--root", str(self.root), *args]

    def spawn(self, *args: str, cwd: Path | None = None) -> Any:
        import subprocess

        return subprocess.Popen(self.argv(*args), cwd=cwd or self.elsewhere,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)

    def run(self, *args: str, cwd: Path | None = None) -> Said:
        proc = self.spawn(*args, cwd=cwd)
        out, err = proc.communicate(timeout=180)
        return Said(["lpam", "--root", str(self.root), *args], proc.returncode, out, err)

    def note(self, when: str, found: list[str]) -> None:
        self.violations += [f"{when}: {v}" for v in found]

    def look(self, when: str) -> tuple[dict[str, Any], str]:
        from tests.integration.several import running

        shown, table = self.run("status", "--json"), self.run("status")
        for said in (shown, table):
            if said.code != 0 or "Traceback" in said.err:
                self.note(when, [f"`lpam status` exit {said.code}: {said.err}"])
        try:
            report = json.loads(shown.out)
        except ValueError:
            self.note(when, [f"`lpam status --json` is not JSON: {shown.out!r}"])
            return {}, table.out
        live = running(self.root)  # the processes: what runs, whatever anyone says
        runs: dict[str, bool | None] = {a["name"]: bool(live.get(a["name"]))
                                        for a in report.get("installed") or []}
        found = both_in_progress_and_cut_off(report, table.out)
        found += running_is_true(report, table.out, runs)
        self.note(when, found)
        return report, table.out

    def check(self, when: str, said: Said | None) -> None:
        time.sleep(1.2)  # supervisord's startsecs: a copy that could not start has gone
        report, table = self.look(when)
        texts = [("status", table), ("status --json", json.dumps(report))]
        if said is not None:
            texts += [(shlex.join(said.argv[3:]), said.out + said.err)]
        if said is not None and said.began:
            self.note(when, last_apply_as_it_ended(report, table, applied(said),
                                                   said.code))
        if self.wished is not None:
            plan = self.run("plan", "--json", "-f", str(self.wished))
            steps: list[str] = []
            text = plan.err
            if plan.code == 0:
                from reconciler.core.planning.render import render
                from schemas.plan import Plan

                made = Plan.model_validate_json(plan.out)
                steps = proposed(made)
                text = Calling.of(self.root).spell(render(made)) + "\n" + plan.err
            else:
                self.note(when, [f"`lpam plan` exit {plan.code}: {plan.err.strip()}"])
            self.note(when, plan_agrees(report, table, steps, text))
            texts += [("plan", text)]
        self.last_hints = hints(texts)
        for hint in self.last_hints:
            self.note(when, hint_as_printed(hint, self.root))

    def follow(self, index: int) -> Said | None:
        """A suggested command that names this root, run as printed from another directory
        at a terminal that answers `yes` (one without --root is a violation already, and
        would act on /)."""
        import pty
        import subprocess
        import sys

        usable = [h for h in self.last_hints if h.argv and "--root" in h.argv
                  and str(self.root) in h.argv]
        if not usable:
            return None
        hint = usable[index % len(usable)]
        argv = hint.argv or []
        before = last_apply(self.root)
        main, terminal = pty.openpty()
        try:
            proc = subprocess.Popen([sys.executable, "-m", "reconciler", *argv[1:]],
                                    cwd=self.elsewhere, stdin=terminal,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True, start_new_session=True)
            os.write(main, b"yes\n")
            out, err = proc.communicate(timeout=180)
        finally:
            os.close(main)
            os.close(terminal)
        wished = applies(argv, self.root)
        if wished is not None and wished.exists():  # what the plan is compared with now
            self.wished = wished
        self.note(f"running `{hint.text}`", failed_as_printed(hint, proc.returncode, err))
        return Said(argv, proc.returncode, out, err, began=last_apply(self.root) != before)


def real_round(car: RealCar, url: str, rng: random.Random, number: int) -> None:
    """One command, perhaps with a fault at a random instant, then the checks."""
    from tests.integration.several import several
    from tests.integration.test_gates import csv_at

    command = REAL_COMMANDS[number % len(REAL_COMMANDS)] if number < len(REAL_COMMANDS) \
        else rng.choice(REAL_COMMANDS)
    fault = rng.choice(FAULTS)
    apps = rng.choice(SETS)
    cwd = None
    previous = car.wished
    before = last_apply(car.root)
    kept = {path: path.read_text() for path in
            (car.root / "etc/lpam/desired-state.yaml", car.typed / "wish.yaml")
            if path.exists()}
    csv_at(car.lpam, 720.0)  # parked: the gates of a gated desired state are open
    if command in ("apply", "release", "gated"):
        car.lpam.desired(several(url, *apps) + (GATES if command == "gated" else ""))
        car.wished = car.root / "etc/lpam/desired-state.yaml"
        if command == "gated":
            csv_at(car.lpam, 200.0)  # driving
        args = ["apply", "--yes"] + (["--release"] if command == "release" else [])
    elif command == "apply -f":
        (car.typed / "wish.yaml").write_text(several(url, *apps))
        car.wished, cwd = car.typed / "wish.yaml", car.typed
        args = ["apply", "--yes", "-f", "wish.yaml"]
    elif command in ("stop", "start", "stop APP", "start APP"):
        installed = [a["name"] for a in car.lpam.status().get("installed") or []]
        args = [command.split()[0]] + ([rng.choice(installed)] if command.endswith("APP")
                                       and installed else [])
    elif command == "rollback":
        args = ["rollback", "--yes"]
    elif command == "services shutdown":
        args, fault = ["services", "shutdown"], None
    else:  # the service manager dies under the apps
        from tests.reliability.test_faults import supervisord

        pid = supervisord(car.root)
        if pid is not None:
            os.kill(pid, signal.SIGKILL)
        car.history.append(f"{command}")
        car.check(" ; ".join(car.history), None)
        return
    proc = car.spawn(*args, cwd=cwd)
    time.sleep(rng.uniform(0.0, 2.5))
    if proc.poll() is None and fault == "look":
        car.look(f"{' ; '.join(car.history)} ; {shlex.join(args)} (status beside it)")
    elif proc.poll() is None and fault is not None:
        with contextlib.suppress(ProcessLookupError):
            if fault == "SIGKILL":
                os.killpg(proc.pid, signal.SIGKILL)
            else:
                os.kill(proc.pid, getattr(signal, fault))
    else:
        fault = None if fault != "look" else fault
    out, err = proc.communicate(timeout=180)
    said = Said(["lpam", "--root", str(car.root), *args], proc.returncode, out, err,
                began=last_apply(car.root) != before)
    car.history.append(f"{shlex.join(args)} → {proc.returncode} [{fault or '-'}]")
    if args[0] == "apply" and proc.returncode in (-9, 130, 143) and not said.began:
        # Killed before it began: the record never heard of this desired state, so the
        # report cannot speak of it; the operator's edit is undone, as if never made.
        for path, text in kept.items():
            path.write_text(text)
        car.wished = previous
        car.history[-1] += " (nothing began: the desired state put back)"
    when = " ; ".join(car.history)
    if "internal error" in err or ("Traceback" in err and "/reconciler/" in err):
        car.note(when, [f"a traceback or internal error: {err}"])
    csv_at(car.lpam, 720.0)
    car.check(when, said)
    if rng.random() < 0.5:
        followed = car.follow(rng.randrange(6))
        if followed is not None:
            car.history.append(f"(the hint) {shlex.join(followed.argv[1:])} → {followed.code}")
            car.check(" ; ".join(car.history), followed)


def test_what_the_real_lpam_says_agrees_with_itself_and_with_the_car(
        lpam: Any, car_url: str, tmp_path: Path) -> None:
    from tests.integration.several import several

    lpam.desired(several(car_url, "ctl-a", "recorder"))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    car = RealCar(lpam, tmp_path)
    car.wished = lpam.root / "etc/lpam/desired-state.yaml"
    rng = random.Random(SEED)
    for number in range(ROUNDS):
        real_round(car, car_url, rng, number)
    print(f"\n{ROUNDS} rounds, {len(car.violations)} violations")
    assert car.violations == [], "\n".join(car.violations)


# --- the checks themselves ------------------------------------------------------------------


def test_a_car_that_agrees_with_itself_passes_every_check(tmp_path: Path) -> None:
    """The property can pass: an app lpam runs as a unit, applied, planned again, its
    parameter changed — nothing contradicts anything (the checks are not blind failures)."""
    world = run_sequence(tmp_path, [("apply", (("z", 0),), False, Mishap()),
                                    ("apply", (("z", 1),), False, Mishap())])
    assert world.violations == []
    assert [h.split(" [")[0] for h in world.history] == ["apply --yes → 0"] * 2


def test_the_checks_notice_each_kind_of_contradiction() -> None:
    """Each check can fail, on reports made by hand."""
    from tests.consistency import Hint as Suggested

    report: dict[str, Any] = {
        "last_apply": {"shown": "in progress since T (pid 1)", "result": "in progress"},
        "cutover": {"began": "T"},
        "installed": [{"name": "x", "running": True, "verified": False, "status": "running",
                       "said": "running", "held": False},
                      {"name": "z", "running": False, "verified": True, "status": "running",
                       "said": "running", "held": True}],
        "holds": []}
    table = "Last apply: in progress since T\nApply cut off mid-cutover (began T)"
    assert len(both_in_progress_and_cut_off(report, table)) == 1
    assert both_in_progress_and_cut_off(
        {**report, "last_apply": {"shown": "in progress since T; cut off"}}, "") != []
    found = plan_agrees(report, table, [], "No changes. The machine matches the desired "
                        "state.")
    assert len(found) == 3
    assert "plan proposes nothing, but the report says owed" in found[0]
    assert "z is held (operator stop), and no hold names it" in found[1]
    assert "under holds (['z']) the plan says 'No changes." in found[2]
    assert running_is_true(report, table, {"x": None, "z": False}) == [
        "(c) the table shows x running, and nowhere that this is unverified (its JSON "
        "says verified: false)"]
    assert [v[:30] for v in hint_as_printed(Suggested("lpam apply -f d.yaml", "status"),
                                            Path("/r"))] == [
        "(d) `lpam apply -f d.yaml` (st", "(d) `lpam apply -f d.yaml` (st"]
    assert hint_as_printed(Suggested("lpam --root /r apply -f /d.yaml", "status"),
                           Path("/r")) == []
    assert [h.text for h in hints([("t", "stopped by `lpam stop`; `lpam start APP`; run "
                                    "`lpam --root /r apply`")])] == ["lpam --root /r apply"]
