"""Properties of the real executor and steps, over many machines, wishes and mishaps.

The planner, the executor, the steps, the state record and the generation folders are the
real ones (on a temporary root); only the ports are in-memory twins
(reconciler/adapters/memory.py, adapters/services/memory.py): a store, scripts that model
the vehicle pessimistically and note every moment two apps could share the CAN bus, and a
service manager for `z`, a scriptless app whose unit lpam writes — its operations go
through the same vehicle model and the same mishaps as a script's. For any starting
state (including an app whose script was cut off, and strays from a lost record), any
desired app, a script failing once and lpam dying before, during or after any script:
- the bus is never shared;
- applying again converges (the next plan is empty) with the desired app running;
- after a crash, no script that finished is run again, and the one cut off is run again
  only once — the trace equals the uninterrupted one, save that one repetition (a unit
  operation leaves no exit code, so one whose end lpam did not see counts as cut off; it
  is idempotent).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

from hypothesis import example, given, settings
from hypothesis import strategies as st

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import Crash, MemoryScripts, MemoryStore
from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.errors import ServiceError, StepError
from reconciler.base.layout import Layout
from reconciler.base.unit import Unit
from reconciler.core.planning.model import AppTarget, RepoTarget, Targets, generation_id
from reconciler.core.planning.plan import make_plan
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.executor import execute
from reconciler.engine.observe.machine import observe
from reconciler.engine.records import generations
from reconciler.engine.records.state import read_record, write_record
from schemas.record import AppRecord, RepositoryRecord, StateRecord, Stray
from tests.lengths import knob
from tests.records import sole

URL, KEY = "git://h/apps", "lab/apps"
C1, C2 = "a" * 40, "b" * 40
TREES = {("x", C1): "1" * 40, ("x", C2): "2" * 40, ("y", C1): "3" * 40, ("y", C2): "4" * 40,
         ("z", C1): "5" * 40, ("z", C2): "6" * 40}
APPS = "xyz"
COMMAND = ("python3", "run.py")  # z is scriptless: lpam writes and drives its unit
UNIT_OPS = {"install": "install.sh", "uninstall": "uninstall.sh", "start": "start.sh",
            "stop": "stop.sh"}
SCRIPTS = ("install.sh", "uninstall.sh", "start.sh", "stop.sh")
STATUSES = ("installing", "installed", "starting", "running", "stopping", "uninstalling")
NOW = datetime(2026, 11, 22, tzinfo=timezone.utc)
EXAMPLES = knob("LPAM_PROPERTY_EXAMPLES", 150, 3000)  # LPAM_LONG=1: docs/reliability.md


def remote() -> dict[str, dict[str, dict[str, tuple[str, dict[str, str]]]]]:
    files = {s: "" for s in SCRIPTS}
    return {URL: {c: {a: (TREES[(a, c)], files if a != "z" else {"run.py": ""})
                      for a in APPS} for c in (C1, C2)}}


def how(name: str) -> dict[str, str]:
    return {"command": json.dumps(list(COMMAND))} if name == "z" else {}


class BusServices(MemoryServices):
    """The twin service manager, wired to the scripts' model of the vehicle: installing or
    starting `z`'s unit is what its install.sh or start.sh would be, with the same
    failures and crashes (named `z:start.sh` and so on in the trace)."""

    def __init__(self, vehicle: MemoryScripts) -> None:
        super().__init__()
        self.vehicle = vehicle

    def _through(self, op: str, name: str, work: Callable[[], None]) -> None:
        app = name.removeprefix("lpam-app-")
        call = f"{app}:{UNIT_OPS[op]}"
        when = self.vehicle.crash(call)
        if when == "before":
            raise Crash(call)
        self.vehicle.calls.append(call)
        failing = call in self.vehicle.fail
        if not (failing and op in ("stop", "uninstall")):  # pessimistic, as for scripts:
            work()  # a failed start may have started it, a failed stop stopped nothing
        self.vehicle._effect(app, UNIT_OPS[op])
        if when in ("during", "after"):
            raise Crash(call)  # no exit code exists for a unit: both are a cut-off call
        if failing:
            self.vehicle.fail.discard(call)
            raise ServiceError(f"{call} failed")

    def install(self, unit: Unit) -> None:
        self._through("install", unit.name, lambda: MemoryServices.install(self, unit))

    def uninstall(self, name: str) -> None:
        self._through("uninstall", name, lambda: MemoryServices.uninstall(self, name))

    def start(self, name: str) -> None:
        self._through("start", name, lambda: MemoryServices.start(self, name))

    def stop(self, name: str) -> None:
        self._through("stop", name, lambda: MemoryServices.stop(self, name))


@st.composite
def machines(draw: st.DrawFn) -> tuple[StateRecord, list[tuple[str, str]]]:
    """A record (maybe lost: strays instead) and the (app, commit) of what is on disk."""
    if not draw(st.booleans()):
        return StateRecord(), []
    name, commit = draw(st.sampled_from(APPS)), draw(st.sampled_from([C1, C2]))
    params = draw(st.sampled_from([{}, {"K": "1"}]))
    tree = TREES[(name, commit)]
    gen = generation_id(tree, how(name))
    unit = "lpam-app-z" if name == "z" else None
    if draw(st.booleans()):  # the record was lost: the generation is a stray
        stray = Stray(name=name, generation=gen, params=params, service=unit)
        return StateRecord(strays=[stray]), [(name, commit, params)]  # type: ignore[list-item]
    app = AppRecord(name=name, repository=KEY, commit=commit, tree=tree, path=name,
                    params=params, generation=gen, status=draw(st.sampled_from(STATUSES)),
                    command=list(COMMAND) if name == "z" else None, service=unit)
    repo = RepositoryRecord(key=KEY, url=URL, ref=None, commit=commit)
    return StateRecord(lineage="L", serial=1, repositories=[repo], apps=[app]), [
        (name, commit, params)]  # type: ignore[list-item]


wishes = st.one_of(st.none(), st.tuples(st.sampled_from(APPS), st.sampled_from([C1, C2]),
                                        st.sampled_from([{}, {"K": "1"}])))
failures = st.sets(st.sampled_from([f"{a}:{s}" for a in APPS for s in SCRIPTS]), max_size=1)
crashes = st.one_of(st.none(), st.tuples(st.integers(0, 8),
                                         st.sampled_from(["before", "during", "after"])))


class World:
    """One machine on a temporary root, driven through the real executor."""

    def __init__(self, root: Path, record: StateRecord,
                 on_disk: list[tuple[str, str, dict[str, str]]]) -> None:
        self.layout = Layout(root)
        self.store = MemoryStore(layout=self.layout, remotes=remote())
        self.scripts = MemoryScripts(runs_dir=self.layout.runs)
        self.services = BusServices(self.scripts)
        self.clock = 0.0
        for name, commit, params in on_disk:
            self.store.fetch(KEY, URL)
            self.store.checkout(KEY, commit)
            gen = generations.Generation(
                name=name, generation=generation_id(TREES[(name, commit)], how(name)),
                repository=KEY, commit=commit, path=name, tree=TREES[(name, commit)],
                params=params, command=COMMAND if name == "z" else None,
                service="lpam-app-z" if name == "z" else None)
            generations.stage(self.layout, self.store, gen)
            status = sole(record).status if record.apps else "running"
            if status != "installing" or not record.apps:
                self.scripts.installed.add(name)
                if name == "z":  # its unit is written: the manager knows it
                    self.services.known_units.add("lpam-app-z")
            if status in ("starting", "running", "stopping"):
                self.scripts.active.add(name)
                if name == "z":
                    MemoryServices.start(self.services, "lpam-app-z")
        if record.lineage is not None:
            write_record(self.layout, record)

    def targets(self, wish: tuple[str, str, dict[str, str]] | None) -> Targets:
        commit = wish[1] if wish else C1
        app = None if wish is None else AppTarget(
            name=wish[0], repository=KEY, commit=commit, path=wish[0],
            tree=TREES[(wish[0], commit)], params=wish[2],
            command=COMMAND if wish[0] == "z" else None,
            service="lpam-app-z" if wish[0] == "z" else None)
        return Targets(repositories=(RepoTarget(KEY, URL, None, commit),),
                       apps=() if app is None else (app,))

    def monotonic(self) -> float:
        return self.clock

    def sleep(self, seconds: float) -> None:  # time passes only when lpam waits
        self.clock += max(seconds, 0.01)

    def apply(self, wish: tuple[str, str, dict[str, str]] | None) -> bool:
        """One `lpam apply`; True when it ended without an error or a crash."""
        targets = self.targets(wish)
        plan = make_plan(targets, observe(self.layout, self.store, targets, self.services),
                         now=NOW, lpam_version="t")
        ctx = Context(layout=self.layout, store=self.store, scripts=self.scripts,
                      services=self.services, record=read_record(self.layout),
                      clock=lambda: NOW, monotonic=self.monotonic, sleep=self.sleep,
                      folders=DiskFolders(layout=self.layout, store=self.store))
        try:
            execute(plan, ctx, progress=lambda _: None)
        except (StepError, Crash):
            return False
        return True

    def pending(self, wish: tuple[str, str, dict[str, str]] | None) -> list[str]:
        targets = self.targets(wish)
        plan = make_plan(targets, observe(self.layout, self.store, targets, self.services),
                         now=NOW, lpam_version="t")
        return [s.id for s in plan.steps]


def converge(world: World, wish: tuple[str, str, dict[str, str]] | None) -> None:
    for _ in range(4):
        if world.apply(wish) and not world.pending(wish):
            break
    assert world.pending(wish) == [], world.scripts.calls
    record = read_record(world.layout)
    if wish is None:
        assert not record.apps and not record.strays
    else:
        assert sole(record).name == wish[0] and sole(record).running
    assert not world.scripts.violations, world.scripts.violations
    if wish is not None:
        assert world.scripts.active <= {wish[0]}
        gens = {tuple(g) for g in generations.present(world.layout)}
        assert gens == {(wish[0], sole(record).generation)} if record.apps else gens == set()


@settings(max_examples=EXAMPLES, deadline=None)
@given(machines(), wishes, failures)
def test_any_machine_converges_and_the_bus_is_never_shared(
    machine: tuple[StateRecord, list[tuple[str, str, dict[str, str]]]],
    wish: tuple[str, str, dict[str, str]] | None, fail: set[str],
) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        world = World(Path(tmp), *machine)
        world.scripts.fail = set(fail)
        converge(world, wish)


# Found by hypothesis: a stray whose generation is the wished one (same folder, other
# parameters) must be installed with the wished parameters, not the stray's own.
_STRAY_SAME_GENERATION: tuple[StateRecord, list[tuple[str, str, dict[str, str]]]] = (
    StateRecord(strays=[Stray(name="x", generation="111111111111-44136fa3", params={})]),
    [("x", "a" * 40, {})])


@settings(max_examples=EXAMPLES, deadline=None)
@given(machines(), wishes, crashes)
@example(_STRAY_SAME_GENERATION, ("x", "a" * 40, {"K": "1"}), (3, "before"))
def test_a_crash_anywhere_resumes_without_running_a_finished_script_again(
    machine: tuple[StateRecord, list[tuple[str, str, dict[str, str]]]],
    wish: tuple[str, str, dict[str, str]] | None, crash: tuple[int, str] | None,
) -> None:
    with tempfile.TemporaryDirectory() as calm_root, tempfile.TemporaryDirectory() as root:
        calm = World(Path(calm_root), *machine)
        converge(calm, wish)
        world = World(Path(root), *machine)
        seen: list[str] = []

        def crash_at(call: str) -> str | None:
            seen.append(call)
            return crash[1] if crash is not None and len(seen) == crash[0] + 1 else None

        world.scripts.crash = crash_at
        world.apply(wish)
        world.scripts.crash = lambda call: None
        converge(world, wish)
        expected = list(calm.scripts.calls)
        # The call cut off is made once more: a script killed while it ran, or a unit
        # operation (idempotent) whose end lpam did not see — units leave no exit code.
        cut_off = ("during", "after") if crash is not None and len(seen) > crash[0] and \
            seen[crash[0]].startswith("z:") else ("during",)
        if crash is not None and crash[1] in cut_off and len(seen) > crash[0]:
            cut = crash[0]
            expected.insert(cut, expected[cut])
        assert world.scripts.calls == expected


def test_the_model_notices_two_apps_on_the_bus(tmp_path: Path) -> None:
    """The property above can fail: a stop skipped by hand is reported."""
    scripts = MemoryScripts(runs_dir=tmp_path / "runs")
    for name in ("install.sh", "start.sh"):
        (tmp_path / name).write_text("")
    scripts.run("x", tmp_path, "start.sh", {}, run="a" * 32)
    scripts.run("y", tmp_path, "install.sh", {}, run="b" * 32)
    assert scripts.violations == ["y install.sh while ['x'] on the vehicle"]
    assert json.loads((tmp_path / "runs" / f"{'a' * 32}.exit").read_text()) == 0
