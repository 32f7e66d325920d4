"""Several apps at once, through the real planner, executor, steps and state record.

Apps claim exclusive resources: the controllers `c1` and `c2` the panda, the trackers
`g1` and `g2` a serial GPS, the recorder `r` nothing. The vehicle model counts a moment
when an app's install.sh or start.sh runs while another installed or running app claims
one of its resources: two owners. For any car running a valid set of these apps (each in
any lifecycle status, cut off or not), any desired set, a script or a health check
failing once, and lpam dying before, during or after any script:
- a resource never has two owners;
- applying again converges: the desired set runs, nothing else is installed;
- an apply that fails is all-or-nothing: the set that ran before it runs again, as it was;
- a change to one app never runs a script of an app whose entry did not change.
Only the ports are in-memory twins (reconciler/adapters/memory.py), as in
tests/unit/test_convergence.py.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import Crash, MemoryGate, MemoryScripts, MemoryStore
from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.errors import Deferred, StepError
from reconciler.base.layout import Layout
from reconciler.core.planning.model import (
    AppTarget,
    HealthTarget,
    RepoTarget,
    Targets,
    generation_id,
)
from reconciler.core.planning.plan import make_plan
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.executor import execute
from reconciler.engine.observe.machine import observe
from reconciler.engine.records import generations
from reconciler.engine.records.state import read_record, write_record
from schemas.plan import Plan
from schemas.record import AppRecord, RepositoryRecord, StateRecord, history_sets
from tests.lengths import knob
from tests.unit.test_convergence import C1, C2, KEY, NOW, SCRIPTS, STATUSES, URL

CLAIMS = {"c1": {"panda"}, "c2": {"panda"}, "g1": {"gps"}, "g2": {"gps"}, "r": set()}
SLOTS = (("c1", "c2"), ("g1", "g2"), ("r",))  # a valid set takes at most one of each
TREES = {(a, c): f"{i:x}" * 40 for i, (a, c) in enumerate(
    ((a, c) for a in CLAIMS for c in (C1, C2)), start=1)}
EXAMPLES = knob("LPAM_PROPERTY_EXAMPLES", 150, 1000)  # LPAM_LONG=1: docs/reliability.md

Entry = tuple[str, str, tuple[tuple[str, str], ...]]  # app, commit, params


@dataclass
class ClaimingVehicle(MemoryScripts):
    """The vehicle, per resource: an app's install.sh or start.sh while another app on
    the vehicle claims one of its resources is two owners."""

    claims: dict[str, set[str]] = field(default_factory=lambda: CLAIMS)

    def _effect(self, app: str, script: str) -> None:
        others = (self.installed | self.active) - {app}
        rivals = sorted(o for o in others if self.claims[o] & self.claims[app])
        if script in ("install.sh", "start.sh") and rivals:
            self.violations.append(f"{app} {script} while {rivals} hold "
                                   f"{sorted(self.claims[app])}")
        saved, self.violations = self.violations, []
        super()._effect(app, script)  # the bookkeeping, not the one-app rule
        self.violations = saved


def entries(draw: st.DrawFn) -> list[Entry]:
    """A valid set: at most one app of each slot, each at a commit, with parameters."""
    found = []
    for slot in SLOTS:
        name = draw(st.sampled_from((None, *slot)))
        if name is not None:
            params = draw(st.sampled_from([(), (("K", "1"),)]))
            found.append((name, draw(st.sampled_from([C1, C2])), params))
    return found


@st.composite
def cars(draw: st.DrawFn) -> tuple[list[Entry], list[str]]:
    """What is installed, and each app's lifecycle status (a cut-off script or not)."""
    installed = entries(draw)
    return installed, [draw(st.sampled_from(STATUSES)) for _ in installed]


wishes = st.composite(lambda draw: entries(draw))()
failures = st.sets(st.sampled_from([f"{a}:{s}" for a in CLAIMS for s in (*SCRIPTS, "check")]),
                   max_size=1)
crashes = st.one_of(st.none(), st.tuples(st.integers(0, 12),
                                         st.sampled_from(["before", "during", "after"])))


def record_of(name: str, commit: str, params: tuple[tuple[str, str], ...],
              status: str = "running") -> AppRecord:
    tree = TREES[(name, commit)]
    return AppRecord(name=name, repository=KEY, commit=commit, tree=tree, path=name,
                     params=dict(params), generation=generation_id(tree, {}),
                     status=status,
                     resources=sorted(CLAIMS[name]))


class Car:
    """One car on a temporary root, driven through the real executor."""

    def __init__(self, root: Path, installed: list[Entry], statuses: list[str]) -> None:
        self.layout = Layout(root)
        remote = {c: {a: (TREES[(a, c)], {s: "" for s in SCRIPTS}) for a in CLAIMS}
                  for c in (C1, C2)}
        self.store = MemoryStore(layout=self.layout, remotes={URL: remote})
        self.vehicle = ClaimingVehicle(runs_dir=self.layout.runs)
        self.services = MemoryServices()
        self.clock = 0.0
        apps = []
        # Both commits in the store: the apps of this world come from either commit of one
        # repository, whose target is C1 (a shallow fetch of C1 would not bring C2).
        self.store.fetch(KEY, URL)
        for (name, commit, params), status in zip(installed, statuses):
            self.store.checkout(KEY, commit)
            app = record_of(name, commit, params, status)
            generations.stage(self.layout, self.store, generations.Generation(
                **app.model_dump(include={"name", "generation", "repository", "commit",
                                          "path", "tree", "params"})))
            if status != "installing":
                self.vehicle.installed.add(name)
            if status in ("starting", "running", "stopping"):
                self.vehicle.active.add(name)
            apps.append(app)
        if apps:
            repo = RepositoryRecord(key=KEY, url=URL, ref=None, commit=C1)
            write_record(self.layout, StateRecord(lineage="L", repositories=[repo],
                                                  apps=apps))

    def targets(self, wish: list[Entry]) -> Targets:
        apps = tuple(AppTarget(
            name=name, repository=KEY, commit=commit, path=name,
            tree=TREES[(name, commit)], params=dict(params),
            health=HealthTarget(settle_seconds=0, command=("check",)),
            resources=frozenset(CLAIMS[name])) for name, commit, params in wish)
        return Targets((RepoTarget(KEY, URL, None, C1),), apps=apps)

    def _plan(self, wish: list[Entry]) -> Plan:
        targets = self.targets(wish)
        return make_plan(targets, observe(self.layout, self.store, targets, self.services),
                         now=NOW, lpam_version="t")

    def apply(self, wish: list[Entry], gate: MemoryGate | None = None) -> bool:
        """One `lpam apply`; True when it ended without an error or a crash."""
        ctx = Context(layout=self.layout, store=self.store, scripts=self.vehicle,
                      services=self.services, record=read_record(self.layout),
                      clock=lambda: NOW, monotonic=lambda: self.clock,
                      sleep=lambda s: None, gate=gate,
                      folders=DiskFolders(layout=self.layout, store=self.store))
        try:
            execute(self._plan(wish), ctx, progress=lambda _: None)
        except (StepError, Crash):
            return False
        return True

    def pending(self, wish: list[Entry]) -> list[str]:
        return [s.id for s in self._plan(wish).steps]

    def apps(self) -> set[tuple[str, str, tuple[tuple[str, str], ...], str]]:
        return {(a.name, a.commit, tuple(sorted(a.params.items())), a.status)
                for a in read_record(self.layout).apps}


def converge(car: Car, wish: list[Entry]) -> None:
    for _ in range(4):
        if car.apply(wish) and not car.pending(wish):
            break
    assert car.pending(wish) == [], car.vehicle.calls
    assert car.apps() == {(n, c, p, "running") for n, c, p in wish}
    assert car.vehicle.active == {n for n, _, _ in wish}
    assert not car.vehicle.violations, car.vehicle.violations


@settings(max_examples=EXAMPLES, deadline=None)
@given(cars(), wishes, failures, crashes)
def test_a_resource_never_has_two_owners_and_every_car_converges(
    car: tuple[list[Entry], list[str]], wish: list[Entry], fail: set[str],
    crash: tuple[int, str] | None,
) -> None:
    with tempfile.TemporaryDirectory() as root:
        world = Car(Path(root), *car)
        world.vehicle.fail = set(fail)
        seen: list[str] = []

        def crash_at(call: str) -> str | None:
            seen.append(call)
            return crash[1] if crash is not None and len(seen) == crash[0] + 1 else None

        world.vehicle.crash = crash_at
        world.apply(wish)
        world.vehicle.crash = lambda call: None
        assert not world.vehicle.violations, world.vehicle.violations
        converge(world, wish)


@settings(max_examples=EXAMPLES, deadline=None)
@given(wishes, wishes, failures)
def test_a_failed_apply_brings_back_the_whole_set_that_ran_before(
    before: list[Entry], wish: list[Entry], fail: set[str],
) -> None:
    with tempfile.TemporaryDirectory() as root:
        world = Car(Path(root), before, ["running"] * len(before))
        world.vehicle.fail = set(fail)
        if world.apply(wish):
            assert world.apps() == {(n, c, p, "running") for n, c, p in wish}
        else:
            assert world.apps() == {(n, c, p, "running") for n, c, p in before}, \
                world.vehicle.calls
            assert world.vehicle.active == {n for n, _, _ in before}
        assert not world.vehicle.violations, world.vehicle.violations


@settings(max_examples=EXAMPLES, deadline=None)
@given(wishes, wishes)
def test_an_app_whose_entry_did_not_change_runs_no_script(before: list[Entry],
                                                          wish: list[Entry]) -> None:
    with tempfile.TemporaryDirectory() as root:
        world = Car(Path(root), before, ["running"] * len(before))
        assert world.apply(wish)
        same = {n for n, c, p in wish if (n, c, p) in before}
        touched = {call.split(":")[0] for call in world.vehicle.calls}
        assert not same & touched, world.vehicle.calls


def test_the_model_notices_two_owners_of_a_resource(tmp_path: Path) -> None:
    """The properties above can fail: a controller installed beside another is reported,
    a recorder beside a controller is not."""
    vehicle = ClaimingVehicle(runs_dir=tmp_path / "runs")
    for name in ("install.sh", "start.sh"):
        (tmp_path / name).write_text("")
    vehicle.run("c1", tmp_path, "start.sh", {}, run="a" * 32)
    vehicle.run("r", tmp_path, "install.sh", {}, run="b" * 32)
    assert vehicle.violations == []
    vehicle.run("c2", tmp_path, "install.sh", {}, run="c" * 32)
    assert vehicle.violations == ["c2 install.sh while ['c1'] hold ['panda']"]


def test_the_graph_orders_only_what_shares_a_claim(tmp_path: Path) -> None:
    """Switching the controller while a tracker arrives and the recorder runs on: the new
    controller's install needs the old one's uninstall; the tracker needs nothing of
    theirs; the recorder has no step at all."""
    car = Car(tmp_path, [("c1", C1, ()), ("r", C1, ())], ["running", "running"])
    steps = {s.id.split("@")[0]: s for s in car._plan(
        [("c2", C1, ()), ("r", C1, ()), ("g1", C1, ())]).steps}
    assert not [s for s in steps if s.endswith(":r")]
    uninstall = next(s.id for k, s in steps.items() if k == "uninstall:c1")
    assert uninstall in steps["install:c2"].needs
    cutover = {s.id for s in steps.values() if s.phase.value == "cutover"}
    assert not [n for n in steps["install:g1"].needs if n in cutover]
    assert car.apply([("c2", C1, ()), ("r", C1, ()), ("g1", C1, ())])
    assert [c for c in car.vehicle.calls if c.startswith("c")] == [
        "c1:stop.sh", "c1:uninstall.sh", "c2:install.sh", "c2:start.sh", "c2:check"]


def test_apps_that_claim_nothing_change_while_the_car_moves_only_if_the_gates_free_them(
        tmp_path: Path) -> None:
    """`gates.unclaimed: free`: the recorder's new version goes in while the car moves;
    a switch of the controller still waits. Without it (`gated`), everything waits."""
    car = Car(tmp_path, [("c1", C1, ()), ("r", C1, ())], ["running", "running"])
    moving = ["moving: 42.0 km/h"]
    with pytest.raises(Deferred):
        car.apply([("c1", C1, ()), ("r", C2, ())], MemoryGate(moving))
    assert car.vehicle.calls == []
    assert car.apply([("c1", C1, ()), ("r", C2, ())], MemoryGate(moving, unclaimed_free=True))
    assert {c.split(":")[0] for c in car.vehicle.calls} == {"r"}  # the recorder alone
    with pytest.raises(Deferred):
        car.apply([("c2", C1, ()), ("r", C2, ())], MemoryGate(moving, unclaimed_free=True))
    assert ("c1", C1, (), "running") in car.apps()


def test_two_applies_in_one_second_are_two_sets_of_the_history(tmp_path: Path) -> None:
    """The sets of the history are told apart by the apply that wrote them, not by its
    time: every apply here runs at the same instant (found by the CLI tests, where two
    applies within one second made one set and `lpam rollback` a plan of two copies)."""
    car = Car(tmp_path, [], [])
    assert car.apply([("c1", C1, ()), ("r", C1, ())])
    assert car.apply([("c2", C1, ()), ("r", C1, ())])
    assert car.apply([("c2", C1, (("K", "1"),)), ("r", C1, ())])
    sets = history_sets(read_record(car.layout).history)
    assert [sorted(e.app for e in s) for s in sets] == [["c1", "r"], ["c2", "r"], ["c2", "r"]]
