"""Properties of the pure planning core, over many generated machines and desired states.

A small model executes plan steps on a state record the way the real steps do. For any
starting state and any target: executing the plan converges (a second plan is empty);
the CAN hardware never has two apps (install only runs with nothing installed, and an
app is stopped before it is uninstalled); every
preparation step runs before the cutover; and a crash after any step, followed by a new
plan, repeats none of the steps that finished.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from reconciler.planning.model import (
    AppTarget,
    Observed,
    RepoObserved,
    RepoTarget,
    Targets,
    generation_id,
)
from reconciler.planning.plan import make_plan
from schemas.plan import Phase, Step, StepKind
from schemas.record import AppRecord, RepositoryRecord, StateRecord

COMMITS = ("a" * 40, "b" * 40)
TREES = ("1" * 40, "2" * 40)
KEYS = ("lab/apps", "lab/tools")
URLS = ("git://h/one", "git://h/two")
NOW = __import__("datetime").datetime(2026, 11, 22)

params_st = st.sampled_from([{}, {"K": "1"}])


@st.composite
def records(draw: st.DrawFn) -> tuple[StateRecord, frozenset[str]]:
    keys = draw(st.lists(st.sampled_from(KEYS), unique=True))
    repos = [RepositoryRecord(key=k, url=draw(st.sampled_from(URLS)), ref=None,
                              commit=draw(st.sampled_from(COMMITS))) for k in keys]
    app = None
    with_app: bool = draw(st.booleans())
    if repos and with_app:
        tree, params = draw(st.sampled_from(TREES)), draw(params_st)
        app = AppRecord(name=draw(st.sampled_from(["x", "y"])), repository=repos[0].key,
                        commit=repos[0].commit, tree=tree, path="p", params=params,
                        generation=generation_id(tree, params), running=draw(st.booleans()))
    gens = frozenset() if app is None else frozenset({f"{app.name}/{app.generation}"})
    return StateRecord(lineage="L", serial=1, repositories=repos, app=app), gens


@st.composite
def targets(draw: st.DrawFn) -> Targets:
    keys = draw(st.lists(st.sampled_from(KEYS), unique=True))
    repos = tuple(RepoTarget(key=k, url=draw(st.sampled_from(URLS)), ref=None,
                             commit=draw(st.sampled_from(COMMITS))) for k in keys)
    app = None
    with_app: bool = draw(st.booleans())
    if repos and with_app:
        app = AppTarget(name=draw(st.sampled_from(["x", "y"])), repository=repos[0].key,
                        commit=repos[0].commit, path="p", tree=draw(st.sampled_from(TREES)),
                        params=draw(params_st))
    return Targets(repositories=repos, app=app)


def observe(record: StateRecord, gens: frozenset[str]) -> Observed:
    repos = {r.key: RepoObserved(key=r.key, present=True, head=r.commit, origin=r.url)
             for r in record.repositories}
    return Observed(record=record, repositories=repos, generations=gens)


def run(
    step: Step, record: StateRecord, gens: frozenset[str]
) -> tuple[StateRecord, frozenset[str]]:
    """What the real step does to the record and the generation folders."""
    a = step.args
    app = record.app
    if step.kind is StepKind.CHECKOUT:
        entry = RepositoryRecord(key=str(a["key"]), url=str(a["url"]), ref=None,
                                 commit=str(a["commit"]))
        rest = [r for r in record.repositories if r.key != a["key"]]
        return record.model_copy(update={"repositories": [*rest, entry]}), gens
    if step.kind is StepKind.REMOVE:
        rest = [r for r in record.repositories if r.key != a["key"]]
        return record.model_copy(update={"repositories": rest}), gens
    if step.kind is StepKind.STAGE:
        return record, gens | {f"{a['app']}/{a['generation']}"}
    if step.kind is StepKind.INSTALL:
        assert app is None, "two apps would hold the CAN hardware"
        assert f"{a['app']}/{a['generation']}" in gens, "installing an unstaged generation"
        params = a["params"] if isinstance(a["params"], dict) else {}
        new = AppRecord(name=str(a["app"]), repository=str(a["repository"]),
                        commit=str(a["commit"]), tree=str(a["tree"]), path=str(a["path"]),
                        params=params, generation=str(a["generation"]), running=False)
        return record.model_copy(update={"app": new}), gens
    assert app is not None and (app.name, app.generation) == (a["app"], a["generation"])
    if step.kind is StepKind.UNINSTALL:
        assert not app.running, "uninstalling an app that was not stopped"
        return record.model_copy(update={"app": None}), gens
    running = step.kind is StepKind.START
    return record.model_copy(update={"app": app.model_copy(update={"running": running})}), gens


def execute(steps: list[Step], record: StateRecord,
            gens: frozenset[str]) -> tuple[StateRecord, frozenset[str]]:
    for step in steps:
        record, gens = run(step, record, gens)
    return record, gens


@settings(max_examples=400, deadline=None)
@given(records(), targets())
def test_plans_converge_and_keep_the_bus_exclusive(
    start: tuple[StateRecord, frozenset[str]], wanted: Targets
) -> None:
    record, gens = start
    plan = make_plan(wanted, observe(record, gens), now=NOW, lpam_version="t")
    phases = [s.phase for s in plan.steps]
    assert phases == sorted(phases, key=[Phase.PREPARE, Phase.CUTOVER, Phase.CLEANUP].index)
    record, gens = execute(plan.steps, record, gens)
    again = make_plan(wanted, observe(record, gens), now=NOW, lpam_version="t")
    assert again.steps == [], [s.id for s in again.steps]
    assert not again.has_changes
    if wanted.app is not None:
        assert record.app is not None and record.app.running


@settings(max_examples=400, deadline=None)
@given(records(), targets(), st.integers(min_value=0, max_value=10))
def test_a_crash_after_any_step_resumes_without_repeating_finished_steps(
    start: tuple[StateRecord, frozenset[str]], wanted: Targets, crash_after: int
) -> None:
    record, gens = start
    plan = make_plan(wanted, observe(record, gens), now=NOW, lpam_version="t")
    done = plan.steps[: min(crash_after, len(plan.steps))]
    record, gens = execute(done, record, gens)
    resumed = make_plan(wanted, observe(record, gens), now=NOW, lpam_version="t")
    assert not {s.id for s in done} & {s.id for s in resumed.steps}
    record, gens = execute(resumed.steps, record, gens)
    assert make_plan(wanted, observe(record, gens), now=NOW, lpam_version="t").steps == []
