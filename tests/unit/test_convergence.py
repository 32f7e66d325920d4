"""Properties of the real executor and steps, over many machines, wishes and mishaps.

The planner, the executor, the steps, the state record and the generation folders are the
real ones (on a temporary root); only the two ports are in-memory twins
(reconciler/adapters/memory.py): a store, and scripts that model the vehicle
pessimistically and note every moment two apps could share the CAN bus. For any starting
state (including an app whose script was cut off, and strays from a lost record), any
desired app, a script failing once and lpam dying before, during or after any script:
- the bus is never shared;
- applying again converges (the next plan is empty) with the desired app running;
- after a crash, no script that finished is run again, and the one cut off is run again
  only once — the trace equals the uninterrupted one, save that one repetition.
"""

from __future__ import annotations

import json
import os
import tempfile
from datetime import UTC, datetime
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from reconciler import generations
from reconciler.adapters.memory import Crash, MemoryScripts, MemoryStore
from reconciler.adapters.services.memory import MemoryServices
from reconciler.errors import StepError
from reconciler.execution.context import Context
from reconciler.execution.executor import execute
from reconciler.layout import Layout
from reconciler.observe.machine import observe
from reconciler.planning.model import AppTarget, RepoTarget, Targets, generation_id
from reconciler.planning.plan import make_plan
from reconciler.state import read_record, write_record
from schemas.record import AppRecord, RepositoryRecord, StateRecord, Stray

URL, KEY = "git://h/apps", "lab/apps"
C1, C2 = "a" * 40, "b" * 40
TREES = {("x", C1): "1" * 40, ("x", C2): "2" * 40, ("y", C1): "3" * 40, ("y", C2): "4" * 40}
SCRIPTS = ("install.sh", "uninstall.sh", "start.sh", "stop.sh")
STATUSES = ("installing", "installed", "starting", "running", "stopping", "uninstalling")
NOW = datetime(2026, 11, 22, tzinfo=UTC)
EXAMPLES = int(os.environ.get("LPAM_PROPERTY_EXAMPLES", "150"))  # more: docs/reliability.md


def remote() -> dict[str, dict[str, dict[str, tuple[str, dict[str, str]]]]]:
    files = {s: "" for s in SCRIPTS}
    return {URL: {c: {a: (TREES[(a, c)], files) for a in "xy"} for c in (C1, C2)}}


@st.composite
def machines(draw: st.DrawFn) -> tuple[StateRecord, list[tuple[str, str]]]:
    """A record (maybe lost: strays instead) and the (app, commit) of what is on disk."""
    if not draw(st.booleans()):
        return StateRecord(), []
    name, commit = draw(st.sampled_from("xy")), draw(st.sampled_from([C1, C2]))
    params = draw(st.sampled_from([{}, {"K": "1"}]))
    tree = TREES[(name, commit)]
    gen = generation_id(tree, params)
    if draw(st.booleans()):  # the record was lost: the generation is a stray
        return StateRecord(strays=[Stray(name=name, generation=gen, params=params)]), [
            (name, commit, params)]  # type: ignore[list-item]
    app = AppRecord(name=name, repository=KEY, commit=commit, tree=tree, path=name,
                    params=params, generation=gen, status=draw(st.sampled_from(STATUSES)))
    repo = RepositoryRecord(key=KEY, url=URL, ref=None, commit=commit)
    return StateRecord(lineage="L", serial=1, repositories=[repo], app=app), [
        (name, commit, params)]  # type: ignore[list-item]


wishes = st.one_of(st.none(), st.tuples(st.sampled_from("xy"), st.sampled_from([C1, C2]),
                                        st.sampled_from([{}, {"K": "1"}])))
failures = st.sets(st.sampled_from([f"{a}:{s}" for a in "xy" for s in SCRIPTS]), max_size=1)
crashes = st.one_of(st.none(), st.tuples(st.integers(0, 8),
                                         st.sampled_from(["before", "during", "after"])))


class World:
    """One machine on a temporary root, driven through the real executor."""

    def __init__(self, root: Path, record: StateRecord,
                 on_disk: list[tuple[str, str, dict[str, str]]]) -> None:
        self.layout = Layout(root)
        self.store = MemoryStore(layout=self.layout, remotes=remote())
        self.scripts = MemoryScripts(runs_dir=self.layout.runs)
        for name, commit, params in on_disk:
            self.store.fetch(KEY, URL)
            self.store.checkout(KEY, commit)
            gen = generations.Generation(
                app=name, generation=generation_id(TREES[(name, commit)], params), repository=KEY,
                commit=commit, path=name, tree=TREES[(name, commit)], params=params)
            generations.stage(self.layout, self.store, gen)
            status = record.app.status if record.app is not None else "running"
            if status != "installing" or record.app is None:
                self.scripts.installed.add(name)
            if status in ("starting", "running", "stopping"):
                self.scripts.active.add(name)
        if record.lineage is not None:
            write_record(self.layout, record)

    def targets(self, wish: tuple[str, str, dict[str, str]] | None) -> Targets:
        commit = wish[1] if wish else C1
        app = None if wish is None else AppTarget(
            name=wish[0], repository=KEY, commit=commit, path=wish[0],
            tree=TREES[(wish[0], commit)], params=wish[2])
        return Targets(repositories=(RepoTarget(KEY, URL, None, commit),), app=app)

    def apply(self, wish: tuple[str, str, dict[str, str]] | None) -> bool:
        """One `lpam apply`; True when it ended without an error or a crash."""
        targets = self.targets(wish)
        plan = make_plan(targets, observe(self.layout, self.store, targets), now=NOW,
                         lpam_version="t")
        ctx = Context(layout=self.layout, store=self.store, scripts=self.scripts,
                      services=MemoryServices(), record=read_record(self.layout),
                      clock=lambda: NOW)
        try:
            execute(plan, ctx, progress=lambda _: None)
        except (StepError, Crash):
            return False
        return True

    def pending(self, wish: tuple[str, str, dict[str, str]] | None) -> list[str]:
        targets = self.targets(wish)
        plan = make_plan(targets, observe(self.layout, self.store, targets), now=NOW,
                         lpam_version="t")
        return [s.id for s in plan.steps]


def converge(world: World, wish: tuple[str, str, dict[str, str]] | None) -> None:
    for _ in range(4):
        if world.apply(wish) and not world.pending(wish):
            break
    assert world.pending(wish) == [], world.scripts.calls
    record = read_record(world.layout)
    if wish is None:
        assert record.app is None and not record.strays
    else:
        assert record.app is not None and record.app.name == wish[0] and record.app.running
    assert not world.scripts.violations, world.scripts.violations
    if wish is not None:
        assert world.scripts.active <= {wish[0]}
        gens = {tuple(g) for g in generations.present(world.layout)}
        assert gens == {(wish[0], record.app.generation)} if record.app else gens == set()


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


@settings(max_examples=EXAMPLES, deadline=None)
@given(machines(), wishes, crashes)
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
        if crash is not None and crash[1] == "during" and len(seen) > crash[0]:
            cut = crash[0]
            expected.insert(cut, expected[cut])  # the cut-off script, run once more
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
