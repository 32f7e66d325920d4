"""Documents from disk to validated models, with every fault at file:line:column.

load → migrate → validate: the path every desired state, catalog and saved plan takes.
Pydantic's error locations are mapped back onto the YAML tree kept by loading.py. A
desired state comes with its apps' places (`DesiredDocument`), for the faults found only
later, once the apps' catalogs are read (two apps that claim one resource).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from pydantic import BaseModel, ValidationError

from reconciler.base.errors import ConfigError
from reconciler.base.loading import Document, load, read_text
from reconciler.core.written import JsonPositions, parse_json
from schemas.agent import AgentConfig
from schemas.catalog import Catalog, CatalogFault, RawCatalog, normalise
from schemas.desired import DesiredState, duplicate_app
from schemas.kinds import DocumentKind
from schemas.plan import Plan, fingerprint

# Imported inside functions: the migrations (no heavy library, ~18 modules) load only when a
# document is upgraded.


class _Places(Protocol):
    """What places a fault: a parsed document, or a version-1 one seen as the current."""

    def position(self, loc: Iterable[str | int]) -> tuple[int, int]: ...

    def error(self, message: str, loc: Iterable[str | int] = (),
              hint: str | None = None) -> ConfigError: ...


_HINTS = {
    "extra_forbidden": "remove it, or check its spelling against desired-state.example.yaml",
    "missing": "add it",
    "string_type": "quote the value to make it a string",
    "literal_error": "use one of the values shown",
}

_EXAMPLES = {"agent configuration": "the README's agent.yaml (A fleet that follows git)",
             "catalog": "the README's libpanda-apps.yaml (Apps are services)"}
"""Where a misspelt key's right spelling is shown, for documents other than a desired state."""


def validation_error(doc: _Places, exc: ValidationError, what: str) -> ConfigError:
    """The first pydantic complaint as a ConfigError at the offending node."""
    error = exc.errors()[0]
    loc = [p for p in error["loc"] if not (isinstance(p, str) and "[" in p)]
    # Pydantic inserts union-member names ('str', 'function-after[…]') into locations.
    loc = [p for p in loc if not (isinstance(p, str) and p in {"str", "dict", "list"})]
    if isinstance(doc, _V1Places):
        loc = doc.written(loc)
    field = ".".join(str(p) for p in loc) or what
    message = str(error["msg"]).removeprefix("Value error, ")
    if error["type"] == "extra_forbidden":
        message = f"unknown key {loc[-1]!r}" if loc else "unknown key"
    elif error["type"] == "missing":
        message = f"{field} is required"
    else:
        message = f"{field}: {message}"
    hint = _HINTS.get(error["type"])
    if error["type"] == "extra_forbidden" and what in _EXAMPLES:
        hint = f"remove it, or check its spelling against {_EXAMPLES[what]}"
    return doc.error(message, loc, hint)


def _validate(doc: _Places, data: Any, model: type[BaseModel], what: str) -> Any:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise validation_error(doc, exc, what) from None


@dataclass(frozen=True)
class DesiredDocument:
    """A desired state with where it is written: the file (or a source's label, such as
    `fleet.git@c92f32f2ab56/desired-state.yaml`) and each app entry's 1-based (line,
    column), in the order of `desired.apps` (a version-1 file's `app:`, as written).

    The model holds no positions (it is compared and fingerprinted by content); they
    travel beside it, so a copy of the model (`replace(document, desired=…)`) keeps them,
    and what refuses two apps that claim one resource names both apps' places."""

    desired: DesiredState
    path: Path
    places: tuple[tuple[int, int], ...]


def load_desired_document(path: Path) -> DesiredDocument:
    """A desired-state file of any supported version, as the current model with its
    apps' places."""
    return desired_document(load(path))


def load_desired(path: Path) -> DesiredState:
    """A desired-state file of any supported version, as the current model (for callers
    that place no fault at an app's entry)."""
    return load_desired_document(path).desired


def desired_from(doc: Document) -> DesiredState:
    """The desired state in a document already parsed, as the current model alone."""
    return desired_document(doc).desired


def desired_document(doc: Document) -> DesiredDocument:
    """The desired state in a document already parsed (parsing is the costly part: a large
    document is parsed once, whoever looks at it first), with its apps' places.

    A file of version 1 says `app:` where the current model says `apps: [ … ]`: its
    faults are placed by `_V1Places`, at the line and column of the file as written."""
    from migrations import upgrade

    data = upgrade(DocumentKind.DESIRED_STATE, doc.data, path=doc.path, position=doc.position)
    current = str(_mapping(doc.data).get("version")).strip() == str(data["version"])
    placed: _Places = doc if current else _V1Places(doc)
    if placed is doc and "app" in _mapping(doc.data):
        raise doc.error("unknown key 'app': version 2 lists apps under `apps:`", ["app"],
                        "write `apps: [NAME]`, or `version: 1` to keep `app:`")
    _check_duplicate_repositories(placed, data)
    _check_duplicate_apps(placed, data)
    state: DesiredState = _validate(placed, data, DesiredState, "desired state")
    return DesiredDocument(state, doc.path, tuple(placed.position(["apps", i])
                                                  for i in range(len(state.apps))))


def _mapping(data: Any) -> dict[Any, Any]:
    return data if isinstance(data, dict) else {}


class _V1Places:
    """A version-1 document seen through the current model's locations: `apps.0.…` is
    `app.…` in the file (the migration put the one app first), so a fault in the app is
    reported where the user wrote it (the tests of version-1 files are the check)."""

    def __init__(self, doc: Document) -> None:
        self.path, self._doc = doc.path, doc

    @staticmethod
    def written(loc: Iterable[str | int]) -> list[str | int]:
        """`loc` of the current model as the version-1 file writes it."""
        parts = list(loc)
        return ["app", *parts[2:]] if parts[:1] == ["apps"] else parts

    def position(self, loc: Iterable[str | int]) -> tuple[int, int]:
        return self._doc.position(self.written(loc))

    def error(self, message: str, loc: Iterable[str | int] = (),
              hint: str | None = None) -> ConfigError:
        line, column = self.position(loc)
        return ConfigError(message, path=self.path, line=line, column=column, hint=hint)


def _check_duplicate_apps(doc: _Places, data: dict[str, Any]) -> None:
    """An app named twice, refused at its second entry (the model refuses it too, but
    without a place)."""
    apps = data.get("apps")
    seen: dict[str, int] = {}
    for index, item in enumerate(apps if isinstance(apps, list) else []):
        name = item.get("name") if isinstance(item, dict) else item
        if not isinstance(name, str):
            continue
        if name in seen:
            raise doc.error(duplicate_app(name, seen[name]), ["apps", index],
                            "remove one of the two entries")
        seen[name] = index


def _check_duplicate_repositories(doc: _Places, data: dict[str, Any]) -> None:
    seen: dict[str, int] = {}
    repos = data.get("repositories")
    if not isinstance(repos, list):
        return
    for index, item in enumerate(repos):
        if not isinstance(item, dict):
            continue
        name = item.get("repo") or item.get("url")
        if not isinstance(name, str):
            continue
        name = name.removesuffix("/").removesuffix(".git")
        if name in seen:
            raise doc.error(
                f"repository {name} is listed twice (first as item {seen[name] + 1})",
                ["repositories", index],
                "list each repository once; remove one of the two entries",
            )
        seen[name] = index


def load_agent(path: Path) -> AgentConfig:
    """The agent's configuration (`etc/lpam/agent.yaml`), version-checked and validated."""
    if not path.exists():
        raise ConfigError("file not found", path=path,
                          hint="write it (README: A fleet that follows git), or pass "
                          "--config FILE")
    return agent_from(load(path))


def agent_from(doc: Document) -> AgentConfig:
    """The agent's configuration in a document already parsed."""
    from migrations import upgrade

    data = upgrade(DocumentKind.AGENT_CONFIG, doc.data, path=doc.path, position=doc.position)
    config: AgentConfig = _validate(doc, data, AgentConfig, "agent configuration")
    return config


def parse_catalog(path: Path, text: str) -> Catalog:
    """An app catalog (`libpanda-apps.yaml`), either wild shape, normalised."""
    return catalog_from(load(path, text))


def catalog_from(doc: Document) -> Catalog:
    """The app catalog in a document already parsed."""
    if not isinstance(doc.data, dict):
        raise doc.error("an app catalog is a mapping with an `apps:` list", [],
                        "see reference/libpanda-default-apps.libpanda-apps.yaml")
    raw: RawCatalog = _validate(doc, doc.data, RawCatalog, "catalog")
    try:
        return normalise(raw)
    except CatalogFault as exc:
        raise doc.error(str(exc), list(exc.loc)) from None


def load_plan(path: Path) -> Plan:
    """A saved plan file (`lpam plan --out`), version-checked, validated and its seal
    checked — all before any lock is taken: a step of an unknown kind, a missing or
    mistyped field, or a plan edited after it was sealed is refused here, at its line
    and column, not when the step runs. (A version-1 plan's seal is checked on its
    version-1 body by its migration, migrations/plan_v1_to_v2.py.)"""
    text = read_text(path)
    hint = "pass a file written by `lpam plan --out FILE`, or use -f for a desired state"
    plan = parse_json(DocumentKind.PLAN, text, path, Plan, version_key="format_version", hint=hint)
    if plan.fingerprint != fingerprint(plan):
        line, column = JsonPositions(text, "format_version")(["fingerprint"])
        raise ConfigError("the plan's fingerprint does not match its steps (edited or "
                          "corrupt)", path=path, line=line, column=column,
                          hint="make a new plan with `lpam plan --out FILE`")
    return plan
