"""From changes to an ordered list of steps, through a networkx DAG.

The ordering rules are the safety rules of the vehicle, written as edges:
every preparation step (check out, stage a generation) precedes every cutover step, so
network and copying happen while the old app still runs; each app's cutover is a chain,
and an app that arrives is installed only after every app that leaves with a claim in
common was stopped and uninstalled (core/planning/ensemble.py writes both as the steps'
`needs`), so two apps never hold the CAN hardware at once; cleanup (removing
repositories) comes last. A cycle is a bug in these rules and is reported by name rather
than silently broken.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from reconciler.base.errors import PlanError
from reconciler.core.planning import dependencies
from reconciler.core.planning.ensemble import SetPlan
from reconciler.core.planning.lifecycle import step_id
from reconciler.core.planning.model import Observed, Targets
from schemas.plan import Action, Change, CheckoutStep, Phase, RemoveStep, Step, StepKind

if TYPE_CHECKING:
    import networkx as nx

# Imported inside functions: networkx (~300 modules) loads only when a plan's steps are not
# already in order (start-up; tests/integration/test_imports.py: a plan in order loads none).

_PHASE_ORDER = {Phase.PREPARE: 0, Phase.CUTOVER: 1, Phase.CLEANUP: 2}


def steps_for(changes: list[Change], targets: Targets, observed: Observed,
              apps: SetPlan) -> list[Step]:
    """The steps that close the changes, in an order that respects the graph: the
    repositories' and dependencies' here, the apps' as the set's plan chose them."""
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
    for app in targets.apps:
        steps += dependencies.steps(app, observed.deps_by.get(app.name))
    return order(_once([*steps, *apps.steps]))


def _once(steps: list[Step]) -> list[Step]:
    """Two apps that need the same preparation (one ROS build) share its step."""
    once: dict[str, Step] = {}
    for step in steps:
        once.setdefault(step.id, step)
    return list(once.values())


def order(steps: Iterable[Step]) -> list[Step]:
    """Topologically sort the steps under the phase rules and what each step needs
    (core/planning/ensemble.py); stable for equal ranks."""
    steps = list(steps)
    index = {s.id: i for i, s in enumerate(steps)}
    if len(index) != len(steps):
        raise PlanError("two steps of the plan have the same id; this is a bug in lpam")
    ranked = sorted(steps, key=lambda s: (_PHASE_ORDER[s.phase], index[s.id]))
    place = {s.id: i for i, s in enumerate(ranked)}
    if all(need in place and place[need] < place[s.id] for s in ranked for need in s.needs):
        # The phases' order, by plan order within a phase, already puts every step after
        # what it needs (as the planner lists an app's chain and what leaves before what
        # arrives): then the graph's lexicographic topological order is exactly this
        # sort (tests/unit/test_planning.py checks it against the graph). It spares
        # most plans networkx's import, 85 ms of a cold apply's start.
        return ranked
    import networkx as nx

    graph = nx.DiGraph()
    graph.add_nodes_from(index)
    for a in steps:
        for b in steps:
            if _PHASE_ORDER[a.phase] < _PHASE_ORDER[b.phase]:
                graph.add_edge(a.id, b.id)
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
