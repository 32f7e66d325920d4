"""Desired (resolved) against observed: a list of changes, each with a human reason.

Pure: no I/O. The diff returns data and never acts (Terraform's plans, kopf's DiffItem);
every no-op says why nothing needs doing, so a user reading the plan can trust it. An
app's change is its decision's (core/planning/decision.py), the very value its steps
come from; repositories, dependencies and strays are said here.
"""

from __future__ import annotations

from collections.abc import Sequence

from reconciler.core.planning import dependencies
from reconciler.core.planning.ensemble import SetPlan, plan_set
from reconciler.core.planning.lifecycle import strays_refreshed
from reconciler.core.planning.model import (
    Observed,
    RepoTarget,
    Targets,
    short,
)
from schemas.catalog import CATALOG_FILE
from schemas.names import is_hex_commit
from schemas.plan import Action, Change
from schemas.record import RepositoryRecord, Stray


def diff(targets: Targets, observed: Observed, apps: SetPlan | None = None) -> list[Change]:
    """Every repository (desired first, then removed ones), every dependency, every stray
    and every app (installed or desired), in a stable order. `apps`: the set's plan, made
    once for the changes and the steps (`planned`); made here when not given."""
    changes = [_repository(t, observed) for t in targets.repositories]
    wanted = {t.key for t in targets.repositories}
    changes += [
        Change(
            address=f"repository.{rec.key}",
            action=Action.DELETE,
            reason="no longer in the desired state",
            before=_repo_fields(rec),
            warnings=_edits_warning(observed, rec.key, "removing it will be refused"),
        )
        for rec in sorted(observed.record.repositories, key=lambda r: r.key)
        if rec.key not in wanted
    ]
    for app in targets.apps:
        changes += dependencies.changes(app, observed.deps_by.get(app.name))
    record = strays_refreshed(observed.record, observed.stray_live)
    adopted = set(observed.adopt.values())
    changes += _strays([s for s in record.strays if s.name not in adopted])
    apps = apps if apps is not None else apps_planned(targets, observed)
    return _once(changes + [d.change() for d in apps.decisions])


def apps_planned(targets: Targets, observed: Observed) -> SetPlan:
    """The set's plan against the record as observed: each installed app's unit now, the
    units of LPAM's apps, the apps LPAM installed that are adopted."""
    record = strays_refreshed(observed.record, observed.stray_live)
    return plan_set(record, targets.apps, observed.generations, observed.lives,
                    adopt=observed.adopt)


def _once(changes: list[Change]) -> list[Change]:
    """Two apps that need one package or one ROS repository: one change says so."""
    once: dict[str, Change] = {}
    for change in changes:
        once.setdefault(change.address, change)
    return list(once.values())


def _repo_fields(rec: RepositoryRecord) -> dict[str, str | bool | dict[str, str] | None]:
    return {"url": rec.url, "ref": rec.ref, "commit": rec.commit}


def _edits_warning(observed: Observed, key: str, consequence: str) -> list[str]:
    obs = observed.repositories.get(key)
    if obs is None or not obs.local_edits:
        return []
    shown = ", ".join(obs.local_edits[:5]) + (" …" if len(obs.local_edits) > 5 else "")
    return [f"local edits in the checkout ({shown}): {consequence}"]


def _describe_ref(ref: str | None) -> str:
    if ref is None:
        return "default branch"
    return f"commit {ref}" if is_hex_commit(ref) else f"ref {ref}"


def _repository(t: RepoTarget, observed: Observed) -> Change:
    ref = _describe_ref(t.ref)
    if t.as_of_last_fetch:
        ref += " (offline: as of the last fetch)"
    if t.no_catalog:
        return _no_catalog(_repository_change(t, observed, ref))
    return _repository_change(t, observed, ref)


def _no_catalog(change: Change) -> Change:
    """A repository whose commit has no libpanda-apps.yaml offers no app: said, not hidden."""
    warning = (f"{change.address.removeprefix('repository.')} has no {CATALOG_FILE} at "
               f"{short(str((change.after or {}).get('commit')))}: it offers no apps")
    return change.model_copy(update={"warnings": [*change.warnings, warning]})


def _repository_change(t: RepoTarget, observed: Observed, ref: str) -> Change:
    rec = observed.record.repository(t.key)
    obs = observed.repositories.get(t.key)
    after: dict[str, str | bool | dict[str, str] | None] = {
        "url": t.url, "ref": t.ref, "commit": t.commit,
    }
    blocked = "the update will be refused until they are committed elsewhere or removed"
    if rec is None:
        return Change(
            address=f"repository.{t.key}", action=Action.CREATE, after=after,
            reason=f"new repository, {ref} at {short(t.commit)}",
            warnings=_edits_warning(observed, t.key, blocked),
        )
    before = _repo_fields(rec)
    if rec.url != t.url and t.in_store:  # engine/execution/steps/repositories.py
        return Change(
            address=f"repository.{t.key}", action=Action.UPDATE, before=before, after=after,
            reason=f"URL changed from {rec.url} to {t.url}: commit {short(t.commit)} is "
            "already in the store, so no fetch and no network; the new URL is used from "
            "the next fetch on",
            warnings=_edits_warning(observed, t.key, "left as they are"),
        )
    if rec.url != t.url:
        return Change(
            address=f"repository.{t.key}", action=Action.REPLACE, before=before, after=after,
            reason=f"URL changed from {rec.url} to {t.url}: cloned anew from it (a fetch "
            "over the network)",
            warnings=_edits_warning(observed, t.key, blocked),
        )
    head = obs.head if obs is not None and obs.present else None
    if head is None:
        reason = "checkout is missing from the repository store: restored"
    elif t.commit is None:
        reason = f"{ref}: commit known after fetch"
    elif head != t.commit and rec.commit == t.commit:
        reason = f"checkout was moved outside lpam to {short(head)}: restored to {short(t.commit)}"
    elif head != t.commit:
        if t.ref is not None and not is_hex_commit(t.ref) and t.ref == rec.ref:
            reason = f"{ref} moved from {short(rec.commit)} to {short(t.commit)}"
        else:
            reason = f"{ref} at {short(t.commit)} (was {short(rec.commit)})"
    elif rec.ref != t.ref:
        reason = f"ref changed from {rec.ref or 'default branch'} to {t.ref or 'default branch'}"
        reason += f" (same commit {short(t.commit)})"
    else:
        return Change(
            address=f"repository.{t.key}", action=Action.NOOP, before=before, after=after,
            reason=f"{ref} at {short(t.commit)}, already checked out",
            warnings=_edits_warning(observed, t.key, "left as they are"),
        )
    return Change(
        address=f"repository.{t.key}", action=Action.UPDATE, before=before, after=after,
        reason=reason, warnings=_edits_warning(observed, t.key, blocked),
    )


def _strays(strays: Sequence[Stray]) -> list[Change]:
    return [
        Change(
            address=f"stray.{s.name}@{s.generation}", action=Action.DELETE,
            before={"name": s.name, "generation": s.generation, "params": dict(s.params)},
            reason=(f"{s.name} was installed by LPAM (libpanda-app-manager) and is taken "
                    f"over: " if s.folder is not None else
                    f"{s.name} ({s.generation}) is installed on disk but in no state record "
                    "(the record was lost or moved aside): ")
            + ("uninstalled" if s.stopped else "stopped and uninstalled")
            + " with its own scripts before any app is installed",
        )
        for s in strays
    ]
