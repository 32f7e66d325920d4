"""`lpam validate [--kind KIND] PATH`: check any document lpam reads, without touching the
machine, and say in one line which kind it was read as and what it holds.

The kinds are the documents an operator writes or carries: a desired state, an app
catalog (`libpanda-apps.yaml`), an app repository folder, the agent's settings
(`agent.yaml`) and a saved plan (`lpam plan -o`). Which one a file is, is read from the
file itself — from the top-level keys each kind's schema defines, so that a key added to
a schema is known here at once (a saved plan: `format_version`, `steps`; agent settings:
`source`, `vehicle: ID`; a catalog: `apps`; a desired state: `repositories`, `app`). The
kind most keys point to wins; a tie, or a document no kind claims, is refused at its first
key with the kinds it could be, and `--kind` settles it. Each kind is then read by the
same function the command that uses it calls, so what validate accepts, `plan`, `agent`
and `apply PLAN` accept.
"""

from __future__ import annotations

import json
import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any, Union

from reconciler.base.errors import ConfigError
from reconciler.base.loading import Document, load, read_text
from reconciler.base.text import counted
from reconciler.core.documents import agent_from, catalog_from, desired_from, load_plan
from reconciler.core.written import json_position
from schemas.agent import AgentConfig
from schemas.catalog import CATALOG_FILE, Catalog, RawCatalog
from schemas.desired import DesiredState
from schemas.enums import StrEnum
from schemas.plan import Plan

# Imported inside functions: the migrations and the plan's checks (~15-18 modules) load only for
# the kind being validated.


class Kind(StrEnum):
    """The kinds of document `--kind` names (the CLI spells out the same values)."""

    DESIRED = "desired-state"
    CATALOG = "catalog"
    REPOSITORY = "repository"
    AGENT = "agent"
    PLAN = "plan"

    @property
    def label(self) -> str:
        return _LABELS[self]


_LABELS = {Kind.DESIRED: "a desired state", Kind.CATALOG: "an app catalog",
           Kind.REPOSITORY: "an app repository", Kind.AGENT: "agent settings",
           Kind.PLAN: "a saved plan"}
_SHOWN_KEYS = {Kind.DESIRED: "repositories, app", Kind.CATALOG: "apps",
               Kind.AGENT: "source, vehicle", Kind.PLAN: "format_version, steps"}
FILE_KINDS = (Kind.DESIRED, Kind.CATALOG, Kind.AGENT, Kind.PLAN)
_FORCE_HINT = (f"say which with --kind {'|'.join(k.value for k in FILE_KINDS)} (an app "
               "repository is a folder)")


def validate(path: Path, kind: Kind | None = None) -> str:
    """What `path` is, in one line; the first fault as a located ConfigError. `kind`
    forces the reading; without it the document's own keys decide."""
    if path.is_dir():
        if kind not in (None, Kind.REPOSITORY):
            raise ConfigError(f"is a folder, not {Kind(kind).label}", path=path,
                              hint="--kind repository reads a folder; give the file itself")
        return _repository(path)
    if kind is Kind.REPOSITORY:
        raise ConfigError("is a file, not an app repository folder", path=path,
                          hint=f"give the folder that holds {CATALOG_FILE}, or another --kind")
    text = read_text(path)
    guessed = kind is None
    doc: Document | None = None
    if kind is None:
        data, doc = _parse(path, text)
        kind = guess(data, path=path, position=lambda loc: _position(text, doc, loc))
    if kind is Kind.PLAN:
        return _plan(path)
    if doc is None:
        doc = load(path, text)
    try:
        return _read(doc, kind)
    except ConfigError as exc:
        if guessed:  # the reader may have meant another kind: say how to read it so
            exc.hint = f"{exc.hint + ' ' if exc.hint else ''}(read as {kind.label}, from its " \
                "keys; --kind reads it as another kind)"
        raise


Position = Callable[[list[Union[str, int]]], tuple[int, int]]


def guess(data: Any, *, path: Path, position: Position) -> Kind:
    """The kind most of the document's top-level keys belong to; a tie or no claim at all
    is a located ConfigError naming the kinds (the user then passes `--kind`)."""
    if not isinstance(data, dict):
        found = ("nothing" if data is None else "a list" if isinstance(data, list)
                 else "a single value")
        raise ConfigError(
            f"cannot tell which kind of document this is: it holds {found}, while "
            f"{_kinds_and_keys()} are mappings of keys", path=path, line=1, column=1,
            hint=_FORCE_HINT)
    votes: dict[Kind, list[str]] = {}
    for key, value in data.items():
        for kind in _claims(str(key), value):
            votes.setdefault(kind, []).append(str(key))
    if not votes:
        first = next(iter(data), None)
        line, column = position([str(first)] if first is not None else [])
        keys = ", ".join(str(k) for k in data) or "none"
        raise ConfigError(
            f"cannot tell which kind of document this is: none of its keys ({keys}) "
            f"belongs to {_kinds_and_keys()}", path=path, line=line, column=column,
            hint=_FORCE_HINT)
    if "version" in data and Kind.CATALOG in votes:  # a catalog has no `version:`: its
        votes.setdefault(Kind.DESIRED, []).extend(votes.pop(Kind.CATALOG))  # `apps:` is v2's
    most = max(len(keys) for keys in votes.values())
    leaders = [kind for kind in FILE_KINDS if len(votes.get(kind, [])) == most]
    if len(leaders) > 1:
        line, column = position([votes[leaders[1]][0]])
        claims = " and ".join(f"{k.label} ({', '.join(votes[k])})" for k in leaders)
        raise ConfigError(f"cannot tell which kind of document this is: it has the keys of "
                          f"{claims}", path=path, line=line, column=column, hint=_FORCE_HINT)
    return leaders[0]


def _kinds_and_keys() -> str:
    named = [f"{k.label} ({_SHOWN_KEYS[k]}…)" for k in FILE_KINDS]
    return ", ".join(named[:-1]) + " or " + named[-1]


def _claims(key: str, value: Any) -> list[Kind]:
    """The kinds whose schema has `key` at the top. `vehicle` is in two: the agent's is
    the vehicle's id (a string), the desired state's describes its CAN signal (a mapping)."""
    if key == "vehicle":
        return [Kind.DESIRED] if isinstance(value, dict) else [Kind.AGENT]
    return [kind for kind in FILE_KINDS if key in _top_keys(kind)]


def _top_keys(kind: Kind) -> frozenset[str]:
    """Every top-level key of `kind` but `version`, which all YAML kinds share."""
    from migrations.desired_state_v0_to_v1 import KEYS as LPAM_KEYS
    from migrations.desired_state_v1_to_v2 import KEYS as V1_KEYS

    # `apps:` votes for a catalog; a desired state's (version 2) has a `version:` (guess)
    fields = {Kind.DESIRED: {*DesiredState.model_fields, *LPAM_KEYS, *V1_KEYS} - {"apps"},
              Kind.CATALOG: set(RawCatalog.model_fields),
              Kind.AGENT: set(AgentConfig.model_fields),
              Kind.PLAN: set(Plan.model_fields)}[kind]
    return frozenset(fields - {"version"})


def _parse(path: Path, text: str) -> tuple[Any, Document | None]:
    """The document's data, and its YAML tree when it was parsed as YAML. A JSON object
    (a saved plan) is read by `json` first: a plan may hold more values than the YAML
    reader takes, and the tree is needed only for the position of a fault."""
    if text.lstrip().startswith("{"):
        try:
            data = json.loads(text)
        except (ValueError, RecursionError):
            pass
        else:
            if isinstance(data, dict):
                return data, None
    doc = load(path, text)
    return doc.data, doc


def _position(text: str, doc: Document | None, loc: list[str | int]) -> tuple[int, int]:
    """Where `loc` is written: in the YAML tree, or (a JSON object `json` read) placed by
    `json_position`, as `lpam apply PLAN` places it, without composing the text as YAML."""
    if doc is not None:
        return doc.position(loc)
    line, column = json_position(text, loc)
    return (line, column) if line is not None and column is not None else (1, 1)


def _read(doc: Document, kind: Kind) -> str:
    """Read `doc` as `kind` with the function the command using it calls; one line."""
    path = doc.path
    if kind is Kind.CATALOG:
        return f"OK: {path} is an app catalog with {_names(catalog_from(doc))}"
    if kind is Kind.AGENT:
        config = agent_from(doc)
        who = (f"as vehicle {config.vehicle}" if config.vehicle is not None
               else f"as the vehicle named in {config.vehicle_file}"
               if config.vehicle_file is not None else "as this machine's hostname")
        extras = (", signed commits only" if config.trust is not None else "") + \
            (f", waiting up to {config.gate_wait_seconds:g} s for closed update gates"
             if config.gate_wait_seconds else "")
        return (f"OK: {path} is agent settings (version {config.version}): follows "
                f"{config.source.url} (branch {config.source.branch}) {who}, a pass every "
                f"{config.interval_seconds:g} s{extras}")
    state = desired_from(doc)
    names = ", ".join(a.name for a in state.apps) or "none"
    written = str(doc.data.get("version")).strip()
    read_as = "" if written == str(state.version) else f", read as version {state.version}"
    return (f"OK: {path} is a desired state (version {written}){read_as}: "
            f"{counted(len(state.repositories), 'repository', 'repositories')}, "
            f"app{'s' if len(state.apps) > 1 else ''} "
            f"{names}")


def _plan(path: Path) -> str:
    """A saved plan as `lpam apply PLAN` reads it, and refused where apply would refuse
    it whatever the machine (edited, made offline); whether it is stale depends on the
    machine it is applied to, so that is said, not checked."""
    from reconciler.core.planning.plan import fingerprint, unknown_values

    plan = load_plan(path)
    text = read_text(path)
    if plan.fingerprint != fingerprint(plan):
        raise _plan_error(path, text, "fingerprint", "the plan's fingerprint does not match "
                          "its steps (edited or corrupt)",
                          "make a new plan with `lpam plan --out FILE`")
    unknown = unknown_values(plan)
    if plan.offline or unknown:
        raise _plan_error(path, text, "offline" if plan.offline else "steps",
                          "the plan was made offline or holds values still unknown "
                          f"({', '.join(unknown) or 'offline'}); it cannot be applied",
                          "make an exact plan with `lpam plan --out FILE` (with network)")
    return (f"OK: {path} is a saved plan (format {plan.format_version}, lpam "
            f"{plan.lpam_version}, {plan.created_at}): {counted(len(plan.steps), 'step')}; "
            f"`lpam apply {shlex.quote(str(path))}` runs it while the machine's state is still "
            f"at serial {plan.serial}")


def _plan_error(path: Path, text: str, key: str, message: str, hint: str) -> ConfigError:
    line, column = _position(text, None, [key])
    return ConfigError(message, path=path, line=line, column=column, hint=hint)


def _names(catalog: Catalog) -> str:
    names = ", ".join(a.name for a in catalog.apps)
    return f"{counted(len(catalog.apps), 'app')} ({names})" if catalog.apps else "no apps"


def _repository(folder: Path) -> str:
    path = folder / CATALOG_FILE
    if not path.is_file():
        raise ConfigError(f"no {CATALOG_FILE} at the top of this folder", path=folder,
                          hint="an app repository lists its apps in libpanda-apps.yaml")
    doc = load(path)
    catalog = catalog_from(doc)
    for index, app in enumerate(catalog.apps):  # the catalog keeps the document's order
        if not (folder / app.path).is_dir():
            raise doc.error(f"app {app.name}: folder {app.path!r} does not exist",
                            ["apps", index, "path"], "create the folder or fix `path:` in the "
                            "catalog")
    return f"OK: {folder} is an app repository with {_names(catalog)}"
