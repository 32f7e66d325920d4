"""The set of apps: the steps from the recorded apps to the desired ones.

A car runs a set of apps keyed by name; one app is a set of one, planned by this same code.
Each app's own rules (core/planning/lifecycle.py) are applied to it alone: an app is
paired with the installed app of its name, so a change to one app never stops, restarts
or reinstalls another, and each app's cutover is its own chain (`needs`). What ties apps
together is only what they claim (schemas/catalog.py `resources`,
core/planning/resources.py): an app that leaves and one that arrives with a claim in
common are ordered in the step graph (core/planning/graph.py) — the leaving one is stopped
and uninstalled before the arriving one is installed, the cutover per resource — and apps
that share nothing have no edge between them. An app recorded before lpam knew claims
holds the panda (schemas/generation.py). Strays (apps found on disk that no record knows)
may hold anything: their stop and uninstall precede every install. An app LPAM installed
that is a desired app as it is, is adopted in place (`adopt`).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

from reconciler.base.unit import UnitState
from reconciler.core.planning.decision import Decision, decide
from reconciler.core.planning.lifecycle import operated, stray_steps, target_of
from reconciler.core.planning.model import AppTarget, GenerationKey
from schemas.operator import OperatorAction
from schemas.plan import AdoptStep, InstallStep, Phase, StartStep, Step, UninstallStep
from schemas.record import AppRecord, StateRecord


def pairs(record: StateRecord, wanted: Sequence[AppTarget]
          ) -> list[tuple[AppRecord | None, AppTarget | None]]:
    """Each installed app with the wanted app of its name: leaving apps (no wanted app of
    their name) first, in the order they were installed, then the wanted ones in the
    desired state's order."""
    names = {t.name for t in wanted}
    found: list[tuple[AppRecord | None, AppTarget | None]] = [
        (a, None) for a in record.apps if a.name not in names]
    return found + [(record.installed(t.name), t) for t in wanted]


@dataclass(frozen=True)
class SetPlan:
    """The set's plan: each app's decision (in `pairs` order), and every step — the
    strays' first, each app's cutover its own chain, ordered across apps by claims."""

    decisions: tuple[Decision, ...]
    steps: tuple[Step, ...]


def plan_set(record: StateRecord, wanted: Sequence[AppTarget],
             generations: frozenset[GenerationKey],
             lives: Mapping[str, UnitState] | None = None, *, start: bool = True,
             verify: bool = True, adopt: Mapping[str, str] | None = None,
             stopped: Collection[str] = ()) -> SetPlan:
    """From the record's apps (and strays) to `wanted`: one decision per app. `lives`:
    each installed app's unit now, by name; `adopt`: a wanted app that is, as it is, an
    app LPAM installed (its stray's name) — taken over in place; `stopped`: apps not to
    be started (an operator's stop a rollback keeps)."""
    adopt = adopt or {}
    lives = lives or {}
    taken = {name: next(s for s in record.strays if s.name == stray)
             for name, stray in adopt.items()}
    strays = stray_steps([s for s in record.strays if s.name not in adopt.values()])
    decided: list[Decision] = []
    steps: list[Step] = list(strays)
    leaving: list[tuple[AppRecord, Step]] = []
    for old, new in pairs(record, wanted):
        keep = start and not (new is not None and new.name in stopped)
        heirs = () if old is None or new is not None else tuple(
            a for a in wanted if a.resources & old.claims)
        decision = decide(old, new, generations, None if old is None else lives.get(old.name),
                          start=keep, verify=verify,
                          adopted=taken.get(new.name) if new is not None else None,
                          heirs=heirs)
        decided.append(decision)
        own = _chained(list(decision.steps))
        steps += own
        if old is not None:
            leaving += [(old, s) for s in own if isinstance(s, UninstallStep)]
    return SetPlan(tuple(decided), tuple(_claims_ordered(steps, strays, leaving, wanted)))


def operator_steps(record: StateRecord, action: OperatorAction,
                   generations: frozenset[GenerationKey], *,
                   names: Collection[str] | None = None) -> list[Step]:
    """`lpam start|stop|restart` on the installed apps `names` (None: every one), by the
    same rules as any plan: a script that was cut off is finished first, and nothing is
    started beside a stray. The record is restricted to the chosen apps and planned as a
    set, each app kept at its own generation: no other app's step can be among them."""
    chosen = [a for a in record.apps if names is None or a.name in names]
    if not chosen:
        return []
    wanted = [target_of(a) for a in chosen]
    restricted = record.model_copy(update={"apps": [operated(a, action) for a in chosen]})
    return list(plan_set(restricted, wanted, generations,
                         start=action != OperatorAction.STOP, verify=False).steps)


def _chained(steps: list[Step]) -> list[Step]:
    """One app's cutover steps, each after the one before it (its own chain)."""
    chained: list[Step] = []
    before: str | None = None
    for step in steps:
        if step.phase is Phase.CUTOVER:
            if before is not None:
                step = step.model_copy(update={"needs": [*step.needs, before]})
            before = step.id
        chained.append(step)
    return chained


def _claims_ordered(steps: list[Step], strays: list[Step],
                    leaving: list[tuple[AppRecord, Step]],
                    wanted: Sequence[AppTarget]) -> list[Step]:
    """Every install (or adoption, or start of an installed app) after every stray's
    steps, and after the uninstall of each leaving app that claims what it claims."""
    claims = {t.name: t.resources for t in wanted}
    ordered: list[Step] = []
    for step in steps:
        if isinstance(step, (InstallStep, AdoptStep, StartStep)) and step.app is not None:
            mine = claims.get(step.app.name, frozenset())
            needs = [s.id for s in strays]
            needs += [s.id for old, s in leaving
                      if old.name != step.app.name and old.claims & mine]
            needs = [n for n in needs if n not in step.needs]
            if needs:
                step = step.model_copy(update={"needs": [*step.needs, *needs]})
        ordered.append(step)
    return ordered
