"""From changes to an ordered list of steps, through a networkx DAG.

The ordering rules are the safety rules of the vehicle, written as edges:
every preparation step (check out, stage a generation) precedes every cutover step, so
network and copying happen while the old app still runs; the cutover is a chain
stop old → uninstall old → install new → start new, so two apps never hold the CAN
hardware at once; cleanup (removing repositories) comes last. A cycle is a bug in these
rules and is reported by name rather than silently broken.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from reconciler.base.errors import PlanError
from reconciler.core.planning import dependencies
from reconciler.core.planning.ensemble import one_app_world, set_steps
from reconciler.core.planning.lifecycle import refreshed, step_id
from reconciler.core.planning.model import Observed, Targets
from schemas.plan import Action, Change, CheckoutStep, Phase, RemoveStep, Step, StepKind

if TYPE_CHECKING:
    import networkx as nx

_PHASE_ORDER = {Phase.PREPARE: 0, Phase.CUTOVER: 1, Phase.CLEANUP: 2}


def steps_for(changes: list[Change], targets: Targets, observed: Observed) -> list[Step]:
    """The steps that close the changes, in an order that respects the graph."""
    by_address = {c.address: c for c in changes}
    steps: list[Step] = []
    for t in targets.repositories:
        change = by_address.get(f"repository.{t.key}")
        if change is not None and change.action is not Action.NOOP:
            steps.append(
                CheckoutStep(id=step_id(StepKind.CHECKOUT, t.key), phase=Phase.PREPARE,
                             key=t.key, url=t.url, ref=t.ref, commit=t.commit)
            )
    for change in changes:
        if change.action is Action.DELETE and change.address.startswith("repository."):
            key = change.address.removeprefix("repository.")
            steps.append(RemoveStep(id=step_id(StepKind.REMOVE, key), phase=Phase.CLEANUP,
                                    key=key))
    for number, app in enumerate(targets.apps):
        steps += dependencies.steps(app, observed.deps_of(app, number == 0))
    record = refreshed(observed.record, observed.live, observed.stray_live, observed.lives)
    steps += set_steps(record, targets.apps, observed.generations, adopt=observed.adopt)
    return order(_once(steps), chained=one_app_world(record, targets.apps))


def _once(steps: list[Step]) -> list[Step]:
    """Two apps that need the same preparation (one ROS build) share its step."""
    once: dict[str, Step] = {}
    for step in steps:
        once.setdefault(step.id, step)
    return list(once.values())


def order(steps: Iterable[Step], *, chained: bool = True) -> list[Step]:
    """Topologically sort the steps under the phase and cutover rules; stable for equal ranks.
    `chained`: the cutover is one chain in plan order (the one-app world); else each
    app's steps say what they need (core/planning/ensemble.py)."""
    steps = list(steps)
    index = {s.id: i for i, s in enumerate(steps)}
    if len(index) != len(steps):
        raise PlanError("two steps of the plan have the same id; this is a bug in lpam")
    if chained and not any(s.needs for s in steps):
        # Without `needs`, the rules' graph is the phases' total order plus the cutover chain
        # in plan order, and its lexicographic topological order is exactly this sort
        # (tests/unit/test_graph.py checks it against the graph). It spares a plan of
        # repositories networkx's import, 85 ms of a cold apply's start.
        return sorted(steps, key=lambda s: (_PHASE_ORDER[s.phase], index[s.id]))
    import networkx as nx

    graph = nx.DiGraph()
    graph.add_nodes_from(index)
    for a in steps:
        for b in steps:
            if _PHASE_ORDER[a.phase] < _PHASE_ORDER[b.phase]:
                graph.add_edge(a.id, b.id)
    if chained:
        cutover = [s.id for s in steps if s.phase is Phase.CUTOVER]
        graph.add_edges_from(zip(cutover, cutover[1:]))
    for s in steps:
        graph.add_edges_from((need, s.id) for need in s.needs)
    return sort_graph(graph, {s.id: s for s in steps}, index)


def sort_graph(graph: nx.DiGraph, steps: dict[str, Step], index: dict[str, int]) -> list[Step]:
    import networkx as nx

    try:
        ordered = nx.lexicographical_topological_sort(graph, key=lambda n: index.get(n, 0))
        ids = list(ordered)
    except nx.NetworkXUnfeasible:
        cycle = " → ".join(f"{a}" for a, _ in nx.find_cycle(graph))
        raise PlanError(
            f"the steps of the plan form a cycle: {cycle}",
            hint="this is a bug in lpam's ordering rules; please report it with the plan",
        ) from None
    missing = [n for n in ids if n not in steps]
    if missing:
        raise PlanError(f"a step needs {missing[0]}, which is not in the plan")
    return [steps[n] for n in ids]
