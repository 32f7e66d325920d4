"""Dependencies in the pure planner: what the plan says about apt, pip and ROS, and that
everything they need runs before the cutover — and nothing runs when nothing changed."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timezone

import pytest

from reconciler.base.errors import PlanError
from reconciler.core.planning.model import (
    AppTarget,
    Deps,
    DepsObserved,
    GenerationKey,
    Observed,
    RepoObserved,
    RepoTarget,
    RosSource,
    Targets,
    WorkspaceTarget,
)
from reconciler.core.planning.plan import check_plan, make_plan
from reconciler.core.planning.render import render
from schemas.plan import Action, AptStep, BuildStep, Phase, Plan, StepKind
from schemas.record import AppRecord, RepositoryRecord, StateRecord

A, T1 = "a" * 40, "1" * 40
R1, R2 = "17dd12e9" + "0" * 32, "d7134708" + "0" * 32
NOW = datetime(2026, 11, 23, tzinfo=timezone.utc)
WS = WorkspaceTarget(path="/r/home/circles/catkin_ws", user="circles")


def ros(commit: str | None = R1) -> RosSource:
    return RosSource(name="can_to_ros", repo=RepoTarget(
        key="@ros/jmscslgroup/can_to_ros", url="git://127.0.0.1/can_to_ros", ref="main",
        commit=commit))


def target(*, commit: str | None = R1, params: dict[str, str] | None = None) -> AppTarget:
    deps = Deps(apt=("libdiagnostic-updater-dev",), pip=("cantools",), ros=(ros(commit),),
                workspace=WS)
    return AppTarget(name="vsl", repository="o/apps", commit=A, path="vsl", tree=T1,
                     params=params or {}, launch="can_to_ros/vsl.launch", deps=deps)


def installed(app: AppTarget) -> AppRecord:
    assert app.generation is not None
    return AppRecord(name=app.name, repository="o/apps", commit=A, tree=T1, path="vsl",
                     params=app.params, generation=app.generation, status="running",
                     launch=app.launch, service="lpam-app-vsl")


def observed(app: AppRecord | None, deps: DepsObserved) -> Observed:
    record = StateRecord(lineage="L", serial=1, apps=[] if app is None else [app], repositories=[
        RepositoryRecord(key="o/apps", url="git://h/apps", ref="main", commit=A)])
    gens = frozenset() if app is None else frozenset({GenerationKey.of(app.name,
                                                                         app.generation)})
    return Observed(record=record, repositories={
        "o/apps": RepoObserved(key="o/apps", present=True, head=A)}, generations=gens,
        deps_by={"vsl": deps})


def plan_for(app: AppTarget, obs: Observed) -> Plan:
    repos = (RepoTarget(key="o/apps", url="git://h/apps", ref="main", commit=A),)
    return make_plan(Targets(repos, (app,)), obs, now=NOW, lpam_version="t")


MISSING = DepsObserved(apt_missing=("libdiagnostic-updater-dev",),
                       pip_unsatisfied=("cantools",), venv_ready=False, ros_built=False)
READY = DepsObserved()


def test_a_first_install_shows_each_dependency_and_prepares_it_before_the_cutover() -> None:
    plan = plan_for(target(), observed(None, MISSING))
    text = render(plan)
    assert "+ apt.libdiagnostic-updater-dev: missing" in text
    assert "+ pip.cantools: not in the app's environment" in text
    assert "+ ros.can_to_ros: at 17dd12e90000 (build)" in text
    kinds = [s.kind for s in plan.steps]
    first_cutover = next(i for i, s in enumerate(plan.steps) if s.phase is Phase.CUTOVER)
    for kind in (StepKind.APT, StepKind.PIP, StepKind.BUILD):
        assert kinds.index(kind) < first_cutover
    build = next(s for s in plan.steps if isinstance(s, BuildStep))
    assert build.ros == {"can_to_ros": R1}
    assert build.workspace == WS.path and build.user == "circles"


def test_a_new_ros_commit_is_a_rebuild_and_a_new_generation() -> None:
    old = target(commit=R1)
    new = target(commit=R2)
    assert old.generation != new.generation  # the rollback target keeps its own build
    seen = replace(READY, ros_built=False, ros_installed={"can_to_ros": R1})
    plan = plan_for(new, observed(installed(old), seen))
    assert "~ ros.can_to_ros: 17dd12e9 → d7134708 (rebuild)" in render(plan)
    assert StepKind.BUILD in [s.kind for s in plan.steps]


def test_nothing_changed_prepares_nothing() -> None:
    app = target()
    plan = plan_for(app, observed(installed(app), READY))
    assert plan.steps == []
    assert {c.action for c in plan.changes} == {Action.NOOP}


def test_a_params_change_runs_no_apt_pip_or_build() -> None:
    app = target()
    plan = plan_for(target(params={"RATE": "5"}), observed(installed(app), READY))
    kinds = {s.kind for s in plan.steps}
    assert kinds == {StepKind.STOP, StepKind.CONFIGURE, StepKind.START, StepKind.VERIFY}


def test_a_package_removed_behind_lpams_back_is_installed_without_touching_the_app() -> None:
    app = target()
    seen = replace(READY, apt_missing=("libdiagnostic-updater-dev",))
    plan = plan_for(app, observed(installed(app), seen))
    assert [s.kind for s in plan.steps] == [StepKind.APT]
    assert isinstance(plan.steps[0], AptStep)
    assert plan.steps[0].packages == ["libdiagnostic-updater-dev"]


def test_requirements_the_system_satisfies_still_get_the_apps_environment() -> None:
    app = target()
    seen = replace(READY, venv_ready=False)
    plan = plan_for(app, observed(installed(app), seen))
    assert "satisfied by the system's packages" in render(plan)
    assert [s.kind for s in plan.steps][:1] == [StepKind.PIP]


def test_a_ros_commit_known_only_after_fetch_cannot_be_applied() -> None:
    plan = plan_for(target(commit=None), observed(None, MISSING))
    with pytest.raises(PlanError, match=r"build:\(known after fetch\)"):
        check_plan(plan, lineage="L", serial=1, source="p.json")


def test_apps_without_dependencies_keep_their_generation_ids() -> None:
    plain = AppTarget(name="x", repository="o/apps", commit=A, path="x", tree=T1)
    assert plain.how == {}  # ids from before dependencies existed do not change
