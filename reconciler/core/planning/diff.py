"""Desired (resolved) against observed: a list of changes, each with a human reason.

Pure: no I/O. The diff returns data and never acts (Terraform's plans, kopf's DiffItem);
every no-op says why nothing needs doing, so a user reading the plan can trust it.
"""

from __future__ import annotations

from collections.abc import Sequence

from reconciler.base.unit import UnitState
from reconciler.core.planning import dependencies
from reconciler.core.planning.ensemble import pairs
from reconciler.core.planning.lifecycle import same_generation, strays_refreshed
from reconciler.core.planning.model import (
    UNKNOWN,
    AppTarget,
    GenerationKey,
    Observed,
    RepoTarget,
    Targets,
    short,
)
from schemas.catalog import CATALOG_FILE
from schemas.names import is_hex_commit
from schemas.plan import Action, Change
from schemas.record import AppRecord, RepositoryRecord, Stray


def diff(targets: Targets, observed: Observed) -> list[Change]:
    """Every repository (desired first, then removed ones), every dependency, every stray
    and every app (installed or desired), in a stable order."""
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
    strays = strays_refreshed(observed.record, observed.stray_live)
    adopted = set(observed.adopt.values())
    changes += _strays([s for s in strays.strays if s.name not in adopted])
    return _once(changes + _apps(targets, observed))


def _once(changes: list[Change]) -> list[Change]:
    """Two apps that need one package or one ROS repository: one change says so."""
    once: dict[str, Change] = {}
    for change in changes:
        once.setdefault(change.address, change)
    return list(once.values())


def _apps(targets: Targets, observed: Observed) -> list[Change]:
    """One change per app (`app.<name>`), each against the installed app of its name; one
    that leaves says which arriving app takes over what it claims; one that LPAM installed
    as it is desired is adopted."""
    found = []
    for rec, t in pairs(observed.record, targets.apps):
        name = t.name if t is not None else rec.name if rec is not None else ""
        if rec is None and t is not None and t.name in observed.adopt:
            found.append(_adoption(t, observed.adopt[t.name]))
            continue
        change = _app(t, rec, observed.generations, observed.lives.get(name))
        if t is None and rec is not None:
            heirs = [a.name for a in targets.apps if a.resources & rec.claims]
            reason = f"app {rec.name} is no longer desired: stopped and uninstalled"
            if heirs:
                reason += (f" before {', '.join(heirs)}, which claims what it claims "
                           f"({', '.join(sorted(rec.claims))}), is installed")
            change = change.model_copy(update={"reason": reason})
        found.append(change)
    return found


def _adoption(t: AppTarget, stray: str) -> Change:
    """The app LPAM installed is the desired one as it is: taken over in place."""
    return Change(
        address=f"app.{t.name}", action=Action.CREATE,
        after=_app_fields(t.name, t.repository, t.commit, t.params, None),
        reason=f"{t.name}, installed by LPAM as {stray}, is the desired app as it is (same "
        f"files as {t.repository} at {short(t.commit)}): adopted in place — no script runs "
        "and it is not restarted")


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
    if rec.url != t.url:
        return Change(
            address=f"repository.{t.key}", action=Action.REPLACE, before=before, after=after,
            reason=f"URL changed from {rec.url} to {t.url}: cloned anew",
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


def _app_fields(
    name: str, repository: str, commit: str | None, params: dict[str, str], status: str | None
) -> dict[str, str | bool | dict[str, str] | None]:
    fields: dict[str, str | bool | dict[str, str] | None] = {
        "name": name, "repository": repository, "commit": commit, "params": dict(params),
    }
    if status is not None:
        fields["status"] = status
    return fields


_CUT_OFF = {
    "installed": "is installed but not running: started",
    "starting": "was being started when the last apply stopped (start.sh cut off or failed): "
    "started again",
    "installing": "was being installed when the last apply stopped (install.sh cut off or "
    "failed): installed again and started",
    "stopping": "was being stopped when the last apply stopped: stopped, then started again",
    "uninstalling": "was being uninstalled when the last apply stopped: installed again and "
    "started",
}


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


def _app(t: AppTarget | None, rec: AppRecord | None,
         generations: frozenset[GenerationKey], live: UnitState | None = None) -> Change:
    """The change of one app: `t` wanted, `rec` the installed app of its name."""
    before = (
        _app_fields(rec.name, rec.repository, rec.commit, rec.params, rec.status) if rec else None
    )
    after = _app_fields(t.name, t.repository, t.commit, t.params, None) if t else None
    if t is None:
        assert rec is not None, "a pair has an installed app, a wanted one or both"
        return Change(
            address=f"app.{rec.name}", action=Action.DELETE, before=before,
            reason=f"app {rec.name} is no longer desired: stopped and uninstalled",
        )
    address = f"app.{t.name}"
    if rec is None:
        return Change(
            address=address, action=Action.CREATE, after=after,
            reason=f"install {t.name} from {t.repository} at {short(t.commit)}",
        )
    if t.tree is None and t.repository == UNKNOWN:
        # Offline, with several repositories not fetched yet: which one offers the app
        # is unknown, and claiming a move "from X to X" would be a guess.
        return Change(
            address=address, action=Action.UPDATE, before=before, after=after,
            reason=f"{t.name}: which repository offers it, and whether its folder changed, "
            "are known after fetch",
        )
    if rec.repository != t.repository:
        return Change(
            address=address, action=Action.REPLACE, before=before, after=after,
            reason=f"{t.name} now comes from {t.repository} (installed from "
            f"{rec.repository}): the installed one is stopped and uninstalled before the "
            "new one is installed",
        )
    if t.tree is None:
        same_folder = t.commit == rec.commit
        detail = "folder compared after fetch"
    else:
        same_folder = t.tree == rec.tree
        detail = f"folder {rec.tree[:12]} → {t.tree[:12]}"
    command = list(t.command) if t.command is not None else None
    same_how = (rec.command, rec.launch) == (command, t.launch)
    if same_folder and same_how and not same_generation(rec, t, generations):
        return Change(
            address=address, action=Action.UPDATE, before=before, after=after,
            reason=f"{t.name}: its installed folder is missing from disk: copied out of git "
            "again and reinstalled",
        )
    if same_folder and same_how:
        return _same_generation(t, rec, before, after, live)
    what = ["new version (" + detail + ")" if not same_folder else "runs differently"]
    if rec.params != t.params:
        what.append("parameters changed")
    return Change(
        address=address, action=Action.UPDATE, before=before, after=after,
        reason=f"{t.name}: {', '.join(what)}; the old generation is stopped and uninstalled "
        "before the new one is installed",
    )


def _same_generation(
    t: AppTarget, rec: AppRecord, before: dict[str, str | bool | dict[str, str] | None] | None,
    after: dict[str, str | bool | dict[str, str] | None] | None, live: UnitState | None,
) -> Change:
    """The installed generation is the wanted one: parameters, drift, holds, cut-off scripts."""
    def update(reason: str) -> Change:
        return Change(address=f"app.{t.name}", action=Action.UPDATE, before=before,
                      after=after, reason=f"{t.name} {reason}")

    if (rec.params, rec.user) != (t.params, t.user):
        changed = sorted(k for k in set(rec.params) | set(t.params)
                         if rec.params.get(k) != t.params.get(k))
        what = f"parameters changed ({', '.join(changed)})" if changed else "user changed"
        return update(f"{what}: restarted with the new values; no install script runs, no "
                      "new generation")
    runs = live is not None and live.running
    if rec.held:
        if rec.status == "installed" and not runs:
            held = (f"{t.name} was stopped by an operator (`lpam stop`) and stays stopped "
                    "until `lpam start` or a change of the desired state")
            return Change(address=f"app.{t.name}", action=Action.NOOP, before=before, after=after,
                          reason=held, warnings=[held])
        if rec.status in ("installing", "uninstalling"):
            return update(f"{_CUT_OFF[rec.status].split(':')[0]}: installed again; it stays "
                          "stopped, as an operator asked (`lpam stop`)")
        return update("was stopped by an operator (`lpam stop`), but that stop did not "
                      "finish and it may still run: stopped")
    if live is not None and live.running and not live.supervised:
        return update(f"runs without its service manager ({live.describe()}): stopped, then "
                      "started again under a new one (never a second copy beside it)")
    if rec.status == "running" and live is not None and live.known and not live.running:
        return update(f"is not running ({live.describe()}): start")
    if rec.status == "installed" and live is not None and live.running:
        return Change(address=f"app.{t.name}", action=Action.NOOP, before=before, after=after,
                      reason=f"{t.name} runs ({live.describe()}), though lpam did not "
                      "start it", warnings=[f"{t.name} was started outside lpam"])
    unproven = ("; it has not passed its health check since it was installed (the check "
                "was cut off): checked again for a whole settle window" if not rec.good else "")
    if rec.status == "running":
        moved = "" if t.commit == rec.commit else f"; repository now at {short(t.commit)}"
        if unproven:
            return update(f"is running{unproven}")
        return Change(address=f"app.{t.name}", action=Action.NOOP, before=before, after=after,
                      reason=f"{t.name} installed and running, app folder unchanged{moved}")
    return update(_CUT_OFF[rec.status] + unproven)
