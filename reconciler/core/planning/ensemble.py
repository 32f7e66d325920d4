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

from reconciler.core.planning.lifecycle import (
    adopted_steps,
    app_steps,
    operated,
    stray_steps,
    target_of,
)
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


def set_steps(record: StateRecord, wanted: Sequence[AppTarget],
              generations: frozenset[GenerationKey], *, start: bool = True,
              verify: bool = True, adopt: Mapping[str, str] | None = None,
              stopped: Collection[str] = ()) -> list[Step]:
    """The steps from the record's apps (and strays) to `wanted`, each app's own cutover
    a chain (`needs`), ordered across apps only by what they claim. `adopt`: a wanted app
    that is, as it is, an app LPAM installed (its stray's name) — taken over in place.
    `stopped`: apps not to be started (an operator's stop a rollback keeps)."""
    adopt = adopt or {}
    taken = {name: next(s for s in record.strays if s.name == stray)
             for name, stray in adopt.items()}
    strays = stray_steps([s for s in record.strays if s.name not in adopt.values()])
    steps: list[Step] = list(strays)
    leaving: list[tuple[AppRecord, Step]] = []
    for old, new in pairs(record, wanted):
        keep = start and not (new is not None and new.name in stopped)
        if old is None and new is not None and new.name in taken:
            own = adopted_steps(taken[new.name], new, generations, start=keep, verify=verify)
        else:
            own = app_steps(old, new, generations, start=keep, verify=verify)
        own = _chained(own)
        steps += own
        if old is not None:
            leaving += [(old, s) for s in own if isinstance(s, UninstallStep)]
    return _claims_ordered(steps, strays, leaving, wanted)


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
    return set_steps(restricted, wanted, generations, start=action != OperatorAction.STOP,
                     verify=False)


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
