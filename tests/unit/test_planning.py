"""The pure planning core: diff, step graph, plan sealing. No git, no disk, no processes."""

from __future__ import annotations

from datetime import datetime, timezone

import networkx as nx
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reconciler.base.errors import PlanError, StalePlanError
from reconciler.core.planning.diff import diff
from reconciler.core.planning.graph import order, sort_graph
from reconciler.core.planning.model import (
    AppTarget,
    GenerationKey,
    Observed,
    RepoObserved,
    RepoTarget,
    Targets,
    generation_id,
)
from reconciler.core.planning.plan import check_plan, make_plan
from reconciler.core.planning.render import render
from schemas.generation import AppGeneration
from schemas.plan import (
    Action,
    CheckoutStep,
    Phase,
    RemoveStep,
    StartStep,
    Step,
    StepKind,
    StopStep,
)
from schemas.record import AppRecord, RepositoryRecord, StateRecord, Stray

A, B, C = "a" * 40, "b" * 40, "c" * 40
T1, T2 = "1" * 40, "2" * 40
NOW = datetime(2026, 11, 22, tzinfo=timezone.utc)


def _generation(step: Step) -> str | None:
    app = getattr(step, "app", None)
    return app.generation if isinstance(app, AppGeneration) else None


def start_step(ident: str, phase: Phase) -> Step:
    app = AppGeneration(name="x", generation="g", repository="r", commit=None, path=None,
                        tree=None)
    return StartStep(id=ident, phase=phase, app=app, good=False)


def repo(commit: str | None = A, ref: str | None = "main", url: str = "git://h/apps") -> RepoTarget:
    return RepoTarget(key="o/apps", url=url, ref=ref, commit=commit)


def app(name: str = "x", tree: str | None = T1, params: dict[str, str] | None = None) -> AppTarget:
    return AppTarget(name=name, repository="o/apps", commit=A, path=name, tree=tree,
                     params=params or {})


def installed(name: str = "x", tree: str = T1, running: bool = True,
              params: dict[str, str] | None = None) -> AppRecord:
    return AppRecord(name=name, repository="o/apps", commit=A, tree=tree, path=name,
                     params=params or {}, generation=generation_id(tree, params or {}),
                     status="running" if running else "installed")


def observed(*, commit: str | None = A, app_rec: AppRecord | None = None, head: str | None = None,
             edits: tuple[str, ...] = (), url: str = "git://h/apps") -> Observed:
    repos = [] if commit is None else [
        RepositoryRecord(key="o/apps", url=url, ref="main", commit=commit)
    ]
    record = StateRecord(lineage="L", serial=3, repositories=repos,
                         apps=[] if app_rec is None else [app_rec])
    obs = {} if commit is None else {
        "o/apps": RepoObserved(key="o/apps", present=True, head=head or commit, local_edits=edits)
    }
    gens = frozenset() if app_rec is None else frozenset(
        {GenerationKey.of(app_rec.name, app_rec.generation)})
    return Observed(record=record, repositories=obs, generations=gens)


def actions(targets: Targets, obs: Observed) -> dict[str, Action]:
    return {c.address: c.action for c in diff(targets, obs)}


def test_first_apply_creates_repository_and_app() -> None:
    plan = make_plan(Targets((repo(),), (app(),)), observed(commit=None), now=NOW, lpam_version="t")
    assert {c.address: c.action for c in plan.changes} == {
        "repository.o/apps": Action.CREATE, "app.x": Action.CREATE}
    assert [s.kind for s in plan.steps] == [
        StepKind.CHECKOUT, StepKind.STAGE, StepKind.INSTALL, StepKind.START,
        StepKind.VERIFY]
    assert plan.summary == "Plan: 2 to add, 0 to change, 0 to replace, 0 to destroy."


def test_unchanged_machine_is_a_noop_with_reasons() -> None:
    plan = make_plan(Targets((repo(),), (app(),)), observed(app_rec=installed()), now=NOW,
                     lpam_version="t")
    assert not plan.has_changes and plan.steps == []
    assert all(c.reason for c in plan.changes)
    assert "No changes" in render(plan)


def test_branch_moved_is_an_update_but_unchanged_app_folder_is_not_touched() -> None:
    changes = diff(Targets((repo(B),), (app(),)), observed(app_rec=installed()))
    assert changes[0].action is Action.UPDATE and "moved" in changes[0].reason
    assert changes[1].action is Action.NOOP


def test_new_app_folder_replaces_generation_old_first() -> None:
    plan = make_plan(Targets((repo(B),), (app(tree=T2),)), observed(app_rec=installed()), now=NOW,
                     lpam_version="t")
    kinds = [(s.kind, _generation(s)) for s in plan.steps]
    old, new = installed().generation, generation_id(T2, {})
    assert kinds == [
        (StepKind.CHECKOUT, None), (StepKind.STAGE, new), (StepKind.STOP, old),
        (StepKind.UNINSTALL, old), (StepKind.INSTALL, new), (StepKind.START, new),
        (StepKind.VERIFY, new)]


def test_switch_app_deletes_the_old_and_stops_it_before_installing_new() -> None:
    targets = Targets((repo(),), (app("y", tree=T2),))
    plan = make_plan(targets, observed(app_rec=installed("x")), now=NOW, lpam_version="t")
    assert [(c.address, c.action) for c in plan.changes[-2:]] == [
        ("app.x", Action.DELETE), ("app.y", Action.CREATE)]
    ids = [s.id for s in plan.steps]
    assert ids.index(f"stop:x@{installed().generation}") < ids.index(
        f"install:y@{generation_id(T2, {})}")


def test_param_change_is_update_and_installed_not_running_only_starts() -> None:
    assert actions(Targets((repo(),), (app(params={"K": "2"}),)),
                   observed(app_rec=installed(params={"K": "1"})))["app.x"] is Action.UPDATE
    plan = make_plan(Targets((repo(),), (app(),)), observed(app_rec=installed(running=False)),
                     now=NOW, lpam_version="t")
    assert [s.kind for s in plan.steps] == [StepKind.START]


def test_app_null_deletes_and_removed_repository_is_cleaned_up_last() -> None:
    plan = make_plan(Targets(()), observed(app_rec=installed()), now=NOW, lpam_version="t")
    assert [s.kind for s in plan.steps] == [StepKind.STOP, StepKind.UNINSTALL, StepKind.REMOVE]
    assert {c.action for c in plan.changes} == {Action.DELETE}


def test_url_change_is_replace_and_drift_is_restored() -> None:
    assert actions(Targets((repo(url="git://new/apps"),)),
                   observed())["repository.o/apps"] is Action.REPLACE
    change = diff(Targets((repo(),)), observed(head=C))[0]
    assert change.action is Action.UPDATE and "outside lpam" in change.reason


def test_local_edits_warned_on_update() -> None:
    change = diff(Targets((repo(B),)), observed(edits=("a.py",)))[0]
    assert change.warnings and "a.py" in change.warnings[0]
    assert "a.py" in render(make_plan(Targets((repo(B),)), observed(edits=("a.py",)),
                                      now=NOW, lpam_version="t"))


def test_prepare_steps_precede_cutover_whatever_the_input_order() -> None:
    steps = [
        start_step("start:x", Phase.CUTOVER),
        RemoveStep(id="remove:r", phase=Phase.CLEANUP, key="r"),
        CheckoutStep(id="checkout:r2", phase=Phase.PREPARE, key="r2", url="u", ref=None,
                     commit=None),
    ]
    assert [s.id for s in order(steps)] == ["checkout:r2", "start:x", "remove:r"]


@settings(deadline=None)  # no time limit per example: a busy machine (a parallel run) is slow
@given(st.lists(st.sampled_from(list(Phase)), max_size=12))
def test_steps_without_needs_are_ordered_as_the_graph_orders_them(phases: list[Phase]) -> None:
    """`order` skips networkx when no step has `needs`; it must put them where the graph of
    the rules (taken once a step has needs) would. The extra last cleanup step needs the
    first one, which the rules imply anyway, so it only forces the graph."""
    steps: list[Step] = [start_step(f"s{i}", p) for i, p in enumerate(phases)]
    forcing = RemoveStep(id="last", phase=Phase.CLEANUP, key="r",
                         needs=[steps[0].id] if steps else [])
    by_graph = [s.id for s in order([*steps, forcing])]
    assert by_graph[-1] == "last"
    assert [s.id for s in order(steps)] == by_graph[:-1]


def test_cycle_is_an_error_naming_it() -> None:
    steps: dict[str, Step] = {i: start_step(i, Phase.CUTOVER) for i in "ab"}
    graph = nx.DiGraph([("a", "b"), ("b", "a")])
    with pytest.raises(PlanError, match=r"cycle: .*a.*b"):
        sort_graph(graph, steps, {"a": 0, "b": 1})
    with pytest.raises(PlanError, match="cycle"):
        order([steps["a"].model_copy(update={"needs": ["b"]}),
               steps["b"].model_copy(update={"needs": ["a"]})])


def test_saved_plan_refused_when_stale_or_edited() -> None:
    plan = make_plan(Targets((repo(),), (app(),)), observed(commit=None), now=NOW, lpam_version="t")
    check_plan(plan, lineage="L", serial=3, source="p")
    with pytest.raises(StalePlanError, match="serial 3, now 4"):
        check_plan(plan, lineage="L", serial=4, source="p")
    with pytest.raises(StalePlanError, match="lineage"):
        check_plan(plan, lineage="other", serial=3, source="p")
    edited = plan.model_copy(update={"steps": plan.steps[:1]})
    with pytest.raises(PlanError, match="fingerprint"):
        check_plan(edited, lineage="L", serial=3, source="p")


def test_render_uses_terraform_symbols() -> None:
    plan = make_plan(Targets((repo(),), (app("y"),)), observed(app_rec=installed("x")), now=NOW,
                     lpam_version="t")
    text = render(plan)
    assert "  - app.x: app x is no longer desired: stopped and uninstalled" in text
    assert "  + app.y: install y from o/apps" in text
    assert text.rstrip().endswith("Plan: 1 to add, 0 to change, 0 to replace, 1 to destroy.")


def test_missing_generation_folder_is_restaged_and_reinstalled() -> None:
    obs = observed(app_rec=installed())
    obs = Observed(record=obs.record, repositories=obs.repositories)  # folder deleted by hand
    plan = make_plan(Targets((repo(),), (app(),)), obs, now=NOW, lpam_version="t")
    assert plan.changes[-1].action is Action.UPDATE and "missing" in plan.changes[-1].reason
    assert [s.kind for s in plan.steps] == [
        StepKind.STAGE, StepKind.STOP, StepKind.UNINSTALL, StepKind.INSTALL, StepKind.START,
        StepKind.VERIFY]


@pytest.mark.parametrize(("status", "kinds"), [
    ("running", []),
    ("installed", [StepKind.START]),
    ("starting", [StepKind.START]),
    ("installing", [StepKind.INSTALL, StepKind.START]),
    ("stopping", [StepKind.STOP, StepKind.START]),
    ("uninstalling", [StepKind.INSTALL, StepKind.START]),
])
def test_a_cut_off_script_is_finished_or_redone_never_assumed(
    status: str, kinds: list[StepKind]
) -> None:
    rec = installed().model_copy(update={"status": status})
    plan = make_plan(Targets((repo(),), (app(),)), observed(app_rec=rec), now=NOW, lpam_version="t")
    assert [s.kind for s in plan.steps] == kinds
    assert plan.has_changes is bool(kinds)
    if kinds:
        reason = plan.changes[-1].reason
        assert "when the last apply stopped" in reason or "not running" in reason


@pytest.mark.parametrize("status", ["starting", "running", "stopping"])
def test_an_app_that_may_be_active_is_stopped_before_another_is_installed(status: str) -> None:
    rec = installed("x").model_copy(update={"status": status})
    plan = make_plan(Targets((repo(),), (app("y", tree=T2),)), observed(app_rec=rec), now=NOW,
                     lpam_version="t")
    kinds = [s.kind for s in plan.steps if s.phase is Phase.CUTOVER]
    assert kinds == [StepKind.STOP, StepKind.UNINSTALL, StepKind.INSTALL, StepKind.START,
                     StepKind.VERIFY]


@pytest.mark.parametrize("status", ["installing", "installed", "uninstalling"])
def test_an_inactive_app_is_uninstalled_without_stop(status: str) -> None:
    rec = installed("x").model_copy(update={"status": status})
    plan = make_plan(Targets((repo(),), (app("y", tree=T2),)), observed(app_rec=rec), now=NOW,
                     lpam_version="t")
    kinds = [s.kind for s in plan.steps if s.phase is Phase.CUTOVER]
    assert kinds == [StepKind.UNINSTALL, StepKind.INSTALL, StepKind.START, StepKind.VERIFY]


def test_strays_found_on_disk_are_stopped_and_uninstalled_before_any_install() -> None:
    record = StateRecord(strays=[Stray(name="x", generation=installed("x").generation,
                                       params={"K": "1"})])
    obs = Observed(record=record, repositories={},
                   generations=frozenset({GenerationKey.of("x", installed("x").generation)}))
    plan = make_plan(Targets((repo(),), (app("y", tree=T2),)), obs, now=NOW, lpam_version="t")
    ids = [s.id for s in plan.steps]
    stray = f"x@{installed('x').generation} (found on disk)"
    assert ids.index(f"stop:{stray}") < ids.index(f"uninstall:{stray}") < ids.index(
        f"install:y@{generation_id(T2, {})}")
    stop = plan.steps[ids.index(f"stop:{stray}")]
    assert isinstance(stop, StopStep) and stop.stray is not None
    assert stop.stray.params == {"K": "1"}
    change = next(c for c in plan.changes if c.address.startswith("stray."))
    assert change.action is Action.DELETE and "no state record" in change.reason
    # the same app wanted again: it is still cycled through its own scripts first
    same = make_plan(Targets((repo(),), (app("x"),)), obs, now=NOW, lpam_version="t")
    assert [s.kind for s in same.steps if s.phase is Phase.CUTOVER] == [
        StepKind.STOP, StepKind.UNINSTALL, StepKind.INSTALL, StepKind.START, StepKind.VERIFY]


def test_an_app_name_that_is_not_its_folder_name_is_not_reinstalled() -> None:
    rec = installed("alpha.")  # lives in generations/alpha/
    obs = Observed(record=StateRecord(lineage="L", serial=3, repositories=[
        RepositoryRecord(key="o/apps", url="git://h/apps", ref="main", commit=A)], apps=[rec]),
        repositories={"o/apps": RepoObserved(key="o/apps", present=True, head=A)},
        generations=frozenset({GenerationKey("alpha", rec.generation)}))
    plan = make_plan(Targets((repo(),), (app("alpha."),)), obs, now=NOW, lpam_version="t")
    assert plan.steps == []


def test_live_state_refreshes_the_record_both_ways() -> None:
    """The record is the prior state; the service manager says what runs now."""
    from dataclasses import replace

    from reconciler.base.unit import UnitState

    running = installed().model_copy(update={"service": "can"})
    down = replace(observed(app_rec=running), lives={"x": UnitState("can", known=True,
                                                                    active="inactive")})
    plan = make_plan(Targets((repo(),), (app(),)), down, now=NOW, lpam_version="t")
    assert [s.kind for s in plan.steps] == [StepKind.START]
    change = next(c for c in plan.changes if c.address == "app.x")
    assert "is not running (unit can inactive): start" in change.reason
    # installed, yet its unit is active: it may hold the bus, so it is stopped before a switch
    stopped = installed(running=False).model_copy(update={"service": "can"})
    up = replace(observed(app_rec=stopped),
                 lives={"x": UnitState("can", known=True, active="active")})
    switch = make_plan(Targets((repo(),), (app("y", tree=T2),)), up, now=NOW, lpam_version="t")
    kinds = [s.kind for s in switch.steps if s.phase is Phase.CUTOVER]
    assert kinds[:2] == [StepKind.STOP, StepKind.UNINSTALL]
    same = make_plan(Targets((repo(),), (app(),)), up, now=NOW, lpam_version="t")
    assert same.steps == [] and "started outside lpam" in same.changes[-1].warnings[0]
    # a unit this manager cannot know changes nothing: the scripts' word stands
    unknown = replace(observed(app_rec=running), lives={"x": UnitState("can", known=False)})
    assert make_plan(Targets((repo(),), (app(),)), unknown, now=NOW, lpam_version="t").steps == []


def test_an_lpam_app_is_stopped_only_when_its_unit_may_run() -> None:
    from dataclasses import replace

    from reconciler.base.unit import UnitState
    from schemas.record import Stray

    lpam_app = Stray(name="pandarecord", generation="lpam", folder="pandarecord")
    base = replace(observed(commit=None),
                   record=StateRecord(strays=[lpam_app]))

    def cutover(live: dict[str, UnitState]) -> list[StepKind]:
        plan = make_plan(Targets((), (app(),)), replace(base, stray_live=live), now=NOW,
                         lpam_version="t")
        return [s.kind for s in plan.steps if "pandarecord" in s.id]

    assert cutover({}) == [StepKind.STOP, StepKind.UNINSTALL]  # nothing known: stop it
    active = UnitState("pandarecord", known=True, active="active")
    assert cutover({"pandarecord": active}) == [StepKind.STOP, StepKind.UNINSTALL]
    inactive = UnitState("pandarecord", known=True, active="inactive")
    assert cutover({"pandarecord": inactive}) == [StepKind.UNINSTALL]
    unknown = UnitState("pandarecord", known=False)
    assert cutover({"pandarecord": unknown}) == [StepKind.STOP, StepKind.UNINSTALL]
