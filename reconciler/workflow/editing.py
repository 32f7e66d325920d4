"""Edits of the default desired state, applied at once: what the field frontends change.

The phone (Privzone over Bluetooth) and the `libpanda-app-manager` command do not act on
the machine themselves: each of their inputs becomes an edit of the desired state lpam
applies by default (`<root>/etc/lpam/desired-state.yaml`), followed by the very apply
`lpam apply` runs. So a rule — the lock, the gates, validation, the health check and its
rollback — holds for them because it is written once, in the workflow, never in a caller.

An edit is made on ruamel.yaml's round-trip tree (comments, key order and `version:` are
kept), validated exactly as a hand edit would be, and written only once the apply's plan
was made, under the apply lock (`confirm`): a refusal at plan time (an unknown app, a
branch the repository lacks, an unreachable server) leaves the file byte-identical and the
app running. If the cutover then fails (health check rolled back, gates closed, a stop
requested), the old bytes are written back: the file says what runs. Values from a phone
are hostile until checked: option-like, control characters, whitespace and `..` are
refused before any lock is taken, so a bad value never waits on another apply.
"""

from __future__ import annotations

import io
import re
from collections.abc import Callable, Mapping, MutableMapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reconciler.base import roundtrip
from reconciler.base.errors import LpamError
from reconciler.workflow import override
from reconciler.workflow.applying import Applied, ApplyOptions, apply, apply_file
from reconciler.workflow.events import Note, Report
from reconciler.workflow.machine import Machine

if TYPE_CHECKING:
    from schemas.desired import DesiredState
    from schemas.plan import Plan

# Imported inside functions: the engine and schemas (pydantic) load only when an edit runs, each
# edit only the checks it uses; a small start-up gain, as an edit needs most of them.

GITHUB = re.compile(r"^[A-Za-z0-9](?:[A-Za-z0-9-]{0,38})/[A-Za-z0-9._-]{1,100}$")
"""GitHub's alphabet: an owner is letters, digits and '-' (39 at most), a repository
letters, digits, '.', '_' and '-'."""
UNCHANGED = "nothing was changed"

Change = Callable[[Any, "DesiredState"], None]
"""Changes the round-trip tree in place; it is given the current desired state to look
things up in, and raises LpamError to refuse."""


@dataclass(frozen=True)
class Edited:
    """How an edit ended: whether the file changed, and the apply that followed it."""

    changed: bool
    applied: Applied


def checked(what: str, value: str, rule: Callable[[str], str] | None = None) -> str:
    """`value` as a frontend gave it, refused unless it is a plain word: no leading '-'
    (it would read as an option to a command), no whitespace or control character, no
    '..'; then `rule` (the schema's own check for that kind of value)."""
    from reconciler.base.text import escaped, shorten

    shown = shorten(escaped(value), 80)
    if not value:
        raise LpamError(f"the {what} is empty", hint=UNCHANGED)
    if value.startswith("-"):
        raise LpamError(f"the {what} {shown!r} starts with '-' (it would read as an option)",
                        hint=UNCHANGED)
    if any(c.isspace() or not c.isprintable() for c in value):
        raise LpamError(f"the {what} {shown!r} contains whitespace or a control character",
                        hint=UNCHANGED)
    if ".." in value:
        raise LpamError(f"the {what} {shown!r} contains '..'", hint=UNCHANGED)
    if rule is not None:
        try:
            rule(value)
        except ValueError as exc:
            raise LpamError(f"the {what} {shown!r}: {exc}", hint=UNCHANGED) from None
    return value


def github_repository(value: str) -> str:
    """`owner/repo` in GitHub's alphabet (schemas.names checks the rest)."""
    from schemas.names import check_owner_repo

    if not GITHUB.match(value):
        raise ValueError("expected a GitHub repository as owner/repo (letters, digits, "
                         "'-' in the owner; '.', '_', '-' too in the repository)")
    return check_owner_repo(value)


def enable_app(machine: Machine, name: str | None, *, by: str, options: ApplyOptions,
               report: Report) -> Edited:
    """Version 1 (`app:`, one app): `app:` becomes `{name: NAME}` (a fresh entry: another
    app's params are not its own), or `null` for no app; the same app again changes
    nothing in the file.

    Version 2 (`apps:`, several apps side by side): NAME replaces the listed apps that
    claim an exclusive resource NAME claims (the panda, a serial GPS, a unit: see
    core/planning/resources.py) and leaves the others as they are, entries, params and
    comments; NAME claiming nothing is added beside them, and NAME already listed changes
    nothing. A user asks for an app, not for the end of the others: only what cannot run
    beside it goes. The claims are read from the catalogs in the repository store as
    the last fetch left them, with no network (the phone is often out of WiFi); when a
    catalog cannot be read there (a repository never fetched, an app no catalog offers),
    NAME replaces the whole list as before issue 22, and a note says so. The claims read
    here only shape the edit: the plan, under the lock, checks them again from what it
    fetched and refuses two owners of a resource (workflow/planning.py), file unchanged.
    No app (`-u`, the phone's null) is `apps: []`: every app stops, as LPAM's "no app"
    meant."""
    from schemas.names import check_app_name

    if name is not None:
        checked("app name", name, check_app_name)

    def change(tree: Any, current: DesiredState) -> None:
        if _listing(tree):
            if name is None:
                _only(tree, current, None)
                return
            try:
                claims = _claims(machine, current, name)
            except LpamError as exc:
                report(Note(f"{name} replaces every listed app: the catalogs could not be "
                            f"read without network ({exc.message})"))
                _only(tree, current, name)
                return
            beside(tree, current, name, claims)
            return
        entry = tree.get("app")  # a version-1 file: `app:` names at most one app
        if name is None:
            if current.apps:
                roundtrip.replace(tree, "app", None)
        elif [a.name for a in current.apps] == [name]:
            return
        elif isinstance(entry, MutableMapping):  # the same entry, its other keys dropped: its
            _renamed(entry, name)                 # comments stay where they were
        else:
            roundtrip.replace(tree, "app", name if isinstance(entry, str)
                              else roundtrip.mapping({"name": name}))

    return edit(machine, change, by=by, options=options, report=report)


def _listing(tree: Any) -> bool:
    """Whether the file is version 2 (`apps:`), not version 1 (`app:`): an edit keeps
    the version the file was written in (a fleet's editors may read only version 1)."""
    return bool(tree.get("version") != 1)


def _renamed(entry: Any, name: str) -> None:
    roundtrip.replace(entry, "name", name)
    for key in [k for k in entry if k != "name"]:
        roundtrip.drop(entry, key)


def _claims(machine: Machine, current: DesiredState, name: str) -> dict[str, frozenset[str]]:
    """The exclusive resources of each listed app and of `name`, resolved from the
    catalogs with no network (the store as the last fetch left it). Raises LpamError,
    saying why, when one of them cannot be known here."""
    from reconciler.engine.observe.targets import Fetch, resolve
    from schemas.desired import AppSpec

    probe = current.model_copy(update={"apps": [*current.apps, AppSpec(name=name)]})
    targets = resolve(probe, base_dir=machine.layout.desired_state.resolve().parent,
                      store=machine.store(), fetch=Fetch.OFFLINE, root=machine.layout.root)
    unread = [t.name for t in targets.apps if t.tree is None]
    if unread:
        raise LpamError(f"the catalog offering {', '.join(unread)} is not fetched yet")
    return {t.name: t.resources for t in targets.apps}


def beside(tree: Any, current: DesiredState, name: str,
           claims: Mapping[str, frozenset[str]]) -> None:
    """`name` into a version-2 file's `apps:` beside the apps it can run with: it takes
    the place of the first listed app sharing a claim with it (that entry renamed, so its
    comments stay), the other rivals leave, and with no rival it is added last; already
    listed, nothing changes. `claims`: app name → its exclusive resources."""
    if any(a.name == name for a in current.apps):
        return
    entries = tree.get("apps")
    if not entries:
        _only(tree, current, name)
        return
    wanted = claims.get(name, frozenset())
    rivals = [i for i, a in enumerate(current.apps) if claims.get(a.name, frozenset()) & wanted]
    if not rivals:
        flow = entries.fa.flow_style() if hasattr(entries, "fa") else False
        roundtrip.add(entries, None, name if flow else roundtrip.mapping({"name": name}))
        return
    first = rivals[0]
    if isinstance(entries[first], MutableMapping):
        _renamed(entries[first], name)
    else:  # the `NAME` shorthand
        entries[first] = name
    for index in reversed(rivals[1:]):
        roundtrip.drop(entries, index)


def _only(tree: Any, current: DesiredState, name: str | None) -> None:
    """`apps:` of a version-2 file becomes `[NAME]` (its one entry renamed when it had
    one, so its comments stay) or `[]`; unchanged when it already is. No app stops every
    app; NAME alone is the edit when the claims of the apps are not known here."""
    if [a.name for a in current.apps] == ([] if name is None else [name]):
        return
    entries = tree.get("apps")
    if name is not None and entries is not None and len(entries) == 1 and \
            isinstance(entries[0], MutableMapping):
        _renamed(entries[0], name)
        return
    listed = roundtrip.sequence()
    if name is not None:
        listed.append(roundtrip.mapping({"name": name}))
    if "apps" in tree:
        roundtrip.replace(tree, "apps", listed)
    else:
        roundtrip.add(tree, "apps", listed)


def add_repository(machine: Machine, repository: str, branch: str | None, *, by: str,
                   options: ApplyOptions, report: Report) -> Edited:
    """The GitHub repository `owner/repo` at `branch` (None: its default branch) is added
    as `repo:`/`ref:`; one already listed keeps its entry, its ref changed if need be. A
    branch the repository lacks is refused by the plan, before the file is written."""
    from schemas.names import check_ref

    checked("repository", repository, github_repository)
    if branch is not None:
        checked("branch", branch, check_ref)

    def change(tree: Any, current: DesiredState) -> None:
        index = _listed(current, repository)
        if index is None:
            entry = {"repo": repository} if branch is None else \
                {"repo": repository, "ref": branch}
            if tree.get("repositories") is None:
                roundtrip.replace(tree, "repositories", roundtrip.sequence())
            roundtrip.add(tree["repositories"], None, roundtrip.mapping(entry))
            return
        if current.repositories[index].ref == branch:
            return
        item = tree["repositories"][index]
        if branch is None:
            roundtrip.drop(item, "ref")
        elif "ref" in item:
            item["ref"] = branch
        else:
            roundtrip.add(item, "ref", branch)

    return edit(machine, change, by=by, options=options, report=report)


def remove_repository(machine: Machine, repository: str, *, by: str, options: ApplyOptions,
                      report: Report) -> Edited:
    """The repository leaves the desired state (lpam removes its checkout). Refused when
    it is not listed, or when an installed or a desired app comes from it (any of them,
    when several run): the app would lose its source mid-flight; switch apps first."""
    from reconciler.engine.records.state import read_record

    checked("repository", repository)
    installed = read_record(machine.layout).apps

    def change(tree: Any, current: DesiredState) -> None:
        index = _listed(current, repository)
        if index is None:
            listed = ", ".join(s.key for s in current.repositories) or "none"
            raise LpamError(f"repository {repository} is not in the desired state "
                            f"(it lists: {listed})", hint=UNCHANGED)
        spec = current.repositories[index]
        names = {spec.key, spec.repo, spec.url, spec.name} - {None}
        users = [("installed", a.name, a.repository) for a in installed] + \
            [("desired", a.name, a.repository) for a in current.apps]
        for which, app, source in users:
            if source in names:
                raise LpamError(f"the {which} app {app} comes from {repository}",
                                hint=f"enable another app (or none) first; {UNCHANGED}")
        roundtrip.drop(tree["repositories"], index)

    return edit(machine, change, by=by, options=options, report=report)


def set_params(machine: Machine, app: str, params: Mapping[str, str], *, by: str,
               options: ApplyOptions, report: Report) -> Edited:
    """The desired app's `params:` replaced by `params` (the plan restarts the app with
    them: no reinstall). Refused unless `app` is the desired app. Names are checked by
    the schema (no PATH, LD_*…); values may hold spaces but no control character."""
    from schemas.names import check_app_name, check_param_name

    checked("app name", app, check_app_name)
    for key, value in params.items():
        checked("parameter name", key, check_param_name)
        if any(not c.isprintable() for c in value):
            raise LpamError(f"the value of parameter {key} contains a control character",
                            hint=UNCHANGED)

    def change(tree: Any, current: DesiredState) -> None:
        index = next((i for i, a in enumerate(current.apps) if a.name == app), None)
        if index is None:
            listed = ", ".join(f"app {a.name}" for a in current.apps)
            raise LpamError(f"{app} is not the desired app (the desired state names "
                            f"{listed or 'no app'})", hint=f"enable it first; {UNCHANGED}")
        if dict(current.apps[index].params) == dict(params):
            return
        entry = _entry(tree, index, app)
        if "params" in entry and not params:
            roundtrip.drop(entry, "params")
        elif "params" in entry:
            roundtrip.replace(entry, "params", roundtrip.mapping(dict(params)))
        elif params:
            roundtrip.add(entry, "params", roundtrip.mapping(dict(params)))

    return edit(machine, change, by=by, options=options, report=report)


def _entry(tree: Any, index: int, name: str) -> Any:
    """The round-trip mapping of the desired app `name` (item `index` of a version-2
    file's `apps:`, a version-1 file's `app:`), a `NAME` shorthand made a mapping."""
    if _listing(tree):
        entries = tree["apps"]
        if not isinstance(entries[index], MutableMapping):
            entries[index] = roundtrip.mapping({"name": name})
        return entries[index]
    if not isinstance(tree.get("app"), MutableMapping):  # the `app: NAME` shorthand
        roundtrip.replace(tree, "app", roundtrip.mapping({"name": name}))
    return tree["app"]


def update(machine: Machine, *, options: ApplyOptions, report: Report) -> Applied:
    """LPAM's `-p`, the phone's `app_update`: the default desired state applied with
    fetching, so branches move to their tips. Under a local override it is what
    `lpam apply --release` does (workflow/applying.py): the override ends, and the car
    applies its fleet's file again. A fleet car with no local file updates as the agent
    does: one sync pass (fetch the fleet's repository, apply this car's file)."""
    from dataclasses import replace

    path = machine.layout.desired_state
    if override.active(machine) is not None:
        options = replace(options, release=True)
    elif not path.exists() and override.follows_fleet(machine):
        return _sync_pass(machine, options, report)
    return apply_file(machine, path, options=options, confirm=lambda plan: True,
                      report=report)


def _sync_pass(machine: Machine, options: ApplyOptions, report: Report) -> Applied:
    """One pass of the agent (workflow/agent.py), its failure raised as the error it
    recorded, so that the phone and the shim say it and exit non-zero."""
    from reconciler.workflow.agent import one_pass, settings
    from reconciler.workflow.applying import standing

    done = one_pass(machine, settings(machine.layout, None), options=options, wait=None,
                    report=report)
    if done.code != 0:
        raise LpamError(f"the fleet's revision {(done.revision or 'none')[:12]}: "
                        f"{done.result}: {done.reason or 'no reason given'}", hint=done.hint)
    return Applied(1 if done.result == "applied" else 0, standing(machine))


def edit(machine: Machine, change: Change, *, by: str, options: ApplyOptions,
         report: Report) -> Edited:
    """Load the editable desired state, `change` it, validate the result as a hand edit
    is validated, and apply it (see `_apply`). Everything up to the apply happens before
    the lock: a refused edit never waits."""
    from reconciler.base.loading import load
    from reconciler.core.documents import desired_document, desired_from

    found = override.editable(machine)
    doc = load(found.path, found.text, keep_quotes=True)
    current = desired_from(doc)
    _version_one(doc.data, found.path)
    yaml = roundtrip.writer(found.text)
    tree = doc.tree  # the tree validated is the one edited: the text is composed once
    change(tree, current)
    out = io.StringIO()
    yaml.dump(tree, out)
    text = out.getvalue()
    document = desired_document(load(found.path, text))
    return _apply(machine, found, text, document.desired, by=by, options=options,
                  report=report, places=document.places)


def _apply(machine: Machine, found: override.Editable, text: str, desired: DesiredState, *,
           by: str, options: ApplyOptions, report: Report,
           places: Sequence[tuple[int, int]] = ()) -> Edited:
    """The edited text is written when the plan made under the lock is confirmed, and
    the old one put back if the execution fails; with no step to run, it is written after
    (nothing on the machine changes), under the lock again. Either way only if the file
    still holds what the edit began from: two frontends editing at once must not undo
    each other's change (the second is refused, to be made again on the new text).
    `places`: each app's (line, column) in the edited text, as `apply` takes them."""
    from reconciler.engine.execution.lock import apply_lock

    old = None if found.seeded else found.text.encode("utf-8")
    new = text.encode("utf-8")
    written: list[bool] = []

    def confirm(plan: Plan) -> bool:
        _unchanged(found.path, old)
        _put(found.path, new, old)
        written.append(True)
        return True

    machine.warm_network()
    try:
        done = apply(machine, found.path, desired, options=options, confirm=confirm,
                     report=report, places=places)
    except LpamError:
        if written:
            _put(found.path, old, new)
        raise
    if not written:
        with apply_lock(machine.layout, timeout=options.lock_wait()):
            _unchanged(found.path, old)
            _put(found.path, new, old)
    override.begin(machine, by=by, seeded=found.seeded)
    return Edited(changed=new != old, applied=done)


def _unchanged(path: Path, old: bytes | None) -> None:
    """Refuse to write over a desired state that changed since the edit read it."""
    from reconciler.base.reading import read_bounded

    try:
        now = read_bounded(path, limit=len(old or b"") + 1, what="the desired state",
                           hint="")
    except FileNotFoundError:
        now = None
    except LpamError:  # larger than it was: changed
        now = b""
    if now != old:
        raise LpamError("the desired state changed while this edit waited for the lock "
                        "(another edit, or a hand edit)",
                        hint=f"make the edit again on the new desired state; {UNCHANGED}")


def _put(path: Path, data: bytes | None, before: bytes | None) -> None:
    """`path` holds `data` (None: no file), written atomically with the file's mode kept;
    nothing is written when it already holds it."""
    from reconciler.base.atomic import fsync_dir, write_atomic

    if data == before:
        return
    if data is None:
        path.unlink(missing_ok=True)
        fsync_dir(path.parent)
        return
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
    write_atomic(path, data, mode=mode)


EDITABLE = (1, 2)
"""The versions an edit is made in, each in its own terms (`app:` or `apps:`)."""


def _version_one(data: Any, path: Path) -> None:
    """Edits are made in the file's own version's terms, version 1 or 2; an older
    document (LPAM's manifest, version 0.0) is refused rather than edited into a mixture
    of two formats."""
    from reconciler.base.errors import ConfigError

    if not isinstance(data, dict) or data.get("version") not in EDITABLE \
            or isinstance(data.get("version"), bool):
        raise ConfigError("only a version 1 desired state (or a version 2 one) can be "
                          "edited here", path=path, line=1, column=1,
                          hint="convert it with `lpam import-lpam -o FILE` and review it; "
                          f"{UNCHANGED}")


def _listed(current: DesiredState, repository: str) -> int | None:
    """The index of `repository` among the desired repositories: its key, `repo:`,
    `url:` or `name:`; a GitHub name matches whatever its letters' case."""
    wanted = repository.casefold()
    for index, spec in enumerate(current.repositories):
        names = {spec.key, spec.repo, spec.url, spec.name} - {None}
        if any(str(n).casefold() == wanted for n in names):
            return index
    return None
