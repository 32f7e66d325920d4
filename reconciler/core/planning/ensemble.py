"""Several apps at once: the steps from the recorded set of apps to the desired set.

The one-app rules (core/planning/lifecycle.py) are applied to each app on its own: an app is
paired with the installed app of its name, so a change to one app never stops, restarts or
reinstalls another. What ties apps together is only what they claim (schemas/catalog.py
`resources`, core/planning/resources.py): an app that leaves and one that arrives with a claim
in common are ordered in the step graph (core/planning/graph.py) — the leaving one is stopped
and uninstalled before the arriving one is installed, today's cutover per resource — and
apps that share nothing have no edge between them. Strays (apps found on disk that no
record knows) may hold anything: their stop and uninstall precede every install.

A set of at most one app on either side is the one-app world of LPAM and desired state
version 1: the old app is replaced by the new one whatever they claim, exactly as
before several apps (`app_steps` alone, its cutover a single chain).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

from reconciler.core.planning.lifecycle import app_steps, stray_steps
from reconciler.core.planning.model import AppTarget, GenerationKey
from schemas.plan import AdoptStep, InstallStep, Phase, StartStep, Step, UninstallStep
from schemas.record import AppRecord, StateRecord


def one_app_world(record: StateRecord, wanted: Sequence[AppTarget]) -> bool:
    """At most one app recorded and at most one wanted: the old app is simply replaced."""
    return len(record.apps) <= 1 and len(wanted) <= 1


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
              verify: bool = True, adopt: str | None = None,
              stopped: Collection[str] = ()) -> list[Step]:
    """The steps from the record's apps (and strays) to `wanted`, each app's own cutover
    a chain (`needs`), ordered across apps only by what they claim. `stopped`: apps not
    to be started (an operator's stop a rollback keeps)."""
    if one_app_world(record, wanted):
        new = wanted[0] if wanted else None
        keep = start and not (new is not None and new.name in stopped)
        return app_steps(record, new, generations, start=keep, verify=verify, adopt=adopt)
    strays = stray_steps(record)
    alone = record.model_copy(update={"strays": []})
    steps: list[Step] = list(strays)
    leaving: list[tuple[AppRecord, Step]] = []
    for old, new in pairs(record, wanted):
        one = alone.model_copy(update={"apps": [] if old is None else [old]})
        keep = start and not (new is not None and new.name in stopped)
        own = _chained(app_steps(one, new, generations, start=keep, verify=verify))
        steps += own
        if old is not None:
            leaving += [(old, s) for s in own if isinstance(s, UninstallStep)]
    return _claims_ordered(steps, strays, leaving, wanted)


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
