"""The registry: the version of each document this lpam reads, and the chain of steps that
brings an older one up to it (the package's docstring, migrations/__init__.py, says why).

The registry stands above the steps, and the steps above what they share (step.py); no
step imports the registry or the package, and `.importlinter`'s *migrations* contract
holds that order, so the package and its modules import no cycle.

Versions are compared as text after normalising (`1`, `"1"` → `"1"`; `0.0`, `"0.0"` →
`"0.0"`): LPAM's manifest said `version: 0.0`, which is not an integer.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Union

from migrations import (
    agent_status_v1_to_v2,
    car_status_v0_to_v1,
    car_status_v1_to_v2,
    car_status_v2_to_v3,
    desired_state_v0_to_v1,
    desired_state_v1_to_v2,
    generation_meta_v0_to_v1,
    plan_v1_to_v2,
    state_record_v1_to_v2,
    state_record_v2_to_v3,
    state_record_v3_to_v4,
    state_record_v4_to_v5,
    state_record_v5_to_v6,
    state_record_v6_to_v7,
    state_record_v7_to_v8,
)
from migrations.step import MigrationError, Step
from reconciler.base.errors import ConfigError, VersionError
from schemas.kinds import DocumentKind
from schemas.kinds import DocumentKind as K

CURRENT: dict[DocumentKind, int] = {
    K.DESIRED_STATE: 2, K.STATE_RECORD: 8, K.PLAN: 2, K.AGENT_CONFIG: 1, K.AGENT_STATUS: 2,
    K.GENERATION_META: 1, K.CAR_STATUS: 3, K.OVERRIDE: 1,
    K.TIMELINE: 1,
}

# kind -> {from version: (to version, step)}; a chain must end at CURRENT[kind].
STEPS: dict[DocumentKind, dict[str, tuple[str, Step]]] = {
    K.DESIRED_STATE: {"0.0": ("1", desired_state_v0_to_v1.upgrade),
                      "1": ("2", desired_state_v1_to_v2.upgrade)},
    K.STATE_RECORD: {"1": ("2", state_record_v1_to_v2.upgrade),
                     "2": ("3", state_record_v2_to_v3.upgrade),
                     "3": ("4", state_record_v3_to_v4.upgrade),
                     "4": ("5", state_record_v4_to_v5.upgrade),
                     "5": ("6", state_record_v5_to_v6.upgrade),
                     "6": ("7", state_record_v6_to_v7.upgrade),
                     "7": ("8", state_record_v7_to_v8.upgrade)},
    K.PLAN: {"1": ("2", plan_v1_to_v2.upgrade)},
    K.AGENT_CONFIG: {},
    K.AGENT_STATUS: {"1": ("2", agent_status_v1_to_v2.upgrade)},
    K.GENERATION_META: {"0": ("1", generation_meta_v0_to_v1.upgrade)},
    K.CAR_STATUS: {"0": ("1", car_status_v0_to_v1.upgrade),
                   "1": ("2", car_status_v1_to_v2.upgrade),
                   "2": ("3", car_status_v2_to_v3.upgrade)},
    K.OVERRIDE: {},
    K.TIMELINE: {},
}

_MISSING_HINTS: dict[DocumentKind, str] = {
    K.DESIRED_STATE: "add `version: 1` at the top; for an LPAM manifest use `lpam import-lpam`",
    K.STATE_RECORD: "this state record was not written by lpam; move it aside and run "
    "`lpam apply` to write a new one",
    K.PLAN: "this plan was not written by lpam; make a new one with `lpam plan -o FILE`",
    K.AGENT_CONFIG: "add `version: 1` at the top (see the README's fleet section)",
    K.AGENT_STATUS: "this status file was not written by lpam; move it aside",
    K.GENERATION_META: "this file was not written by lpam; move it aside",
    K.CAR_STATUS: "the car publishes a new one with its next status",
    K.OVERRIDE: "this file was not written by lpam; move it aside (the car then follows "
    "its fleet again)",
    K.TIMELINE: "this line was not written by lpam",
}

_NUMBER = re.compile(r"^[0-9]{1,9}(\.[0-9]{1,9})?$")

_LABELS: dict[DocumentKind, str] = {
    K.DESIRED_STATE: "desired state", K.STATE_RECORD: "state record", K.PLAN: "plan",
    K.AGENT_CONFIG: "agent configuration", K.AGENT_STATUS: "agent status",
    K.GENERATION_META: "generation metadata", K.CAR_STATUS: "car's published status",
    K.OVERRIDE: "local override", K.TIMELINE: "timeline",
}

Position = Callable[[Sequence[Union[str, int]]], Union[tuple[int, int], tuple[None, None]]]


def upgrade(
    kind: DocumentKind | str, data: Any, *, path: Path, position: Position | None = None,
    to: int | None = None,
) -> dict[str, Any]:
    """Bring a document of `kind` to CURRENT[kind] by applying pure step functions in order.

    `position` (e.g. `Document.position`) maps a location inside `data` to a 1-based
    (line, column); without it, errors about a specific key carry no line. `data` is not
    modified; the result has `version: CURRENT[kind]` as an int. `to` stops the chain at
    an older version (`lpam import-lpam` writes a version-1 desired state, the dialect the
    field's files speak); a document already past it is returned at its own version.
    """
    if kind not in CURRENT:
        raise ValueError(f"unknown document kind {kind!r}")
    kind = DocumentKind(kind)
    label = _LABELS[kind]
    if not isinstance(data, Mapping):
        # Say what the user wrote in YAML's words, not the parser's class names
        # (a lone `=` reaches here as ruamel's TaggedScalar).
        found = ("nothing" if data is None else "a list" if isinstance(data, list)
                 else "a single value")
        raise ConfigError(
            f"expected a mapping (key: value) at the top of the {label}, found {found}",
            path=path, line=1, column=1, hint=_MISSING_HINTS[kind] if data is None else None,
        )
    doc: dict[str, Any] = dict(data)

    def where(loc: Sequence[str | int]) -> tuple[int | None, int | None]:
        return position(loc) if position is not None else (None, None)

    if doc.get("version") is None:
        raise ConfigError(
            f"the {label} has no `version`", path=path, line=1, column=1,
            hint=_MISSING_HINTS[kind],
        )
    version = _known_version(kind, doc["version"], path, lambda: where(("version",)))
    target = str(CURRENT[kind] if to is None else to)
    while version != target and version in STEPS[kind]:
        version, step = STEPS[kind][version]
        try:
            doc = step(doc)
        except MigrationError as exc:
            line, column = where(exc.loc)
            raise ConfigError(
                exc.message, path=path, line=line, column=column, hint=exc.hint
            ) from None
    doc["version"] = int(version)
    return doc


def _known_version(kind: DocumentKind, value: Any, path: Path,
                   at: Callable[[], tuple[int | None, int | None]]) -> str:
    """The document's version as text, if this lpam reads it; a newer one is refused by
    name (the operator must upgrade lpam, not lose fields silently). `at` finds where the
    version is written only when it is refused: finding it parses the document again for
    positions, which costs more than all the rest (every `lpam status` reads the record)."""
    version = _normalise(value)
    current = str(CURRENT[kind])
    if version is not None and (version == current or version in STEPS[kind]):
        return version
    line, column = at()
    if version is None:
        raise VersionError(
            f"`version` must be a number, not {value!r}",
            path=path, line=line, column=column, hint=f"write `version: {current}`",
        )
    if version != current and version not in STEPS[kind]:
        if _newer(version, CURRENT[kind]):
            raise VersionError(
                f"written by a newer lpam: document version {version}, this lpam reads up "
                f"to {current}",
                path=path, line=line, column=column, hint="upgrade lpam",
            )
        known = ", ".join([*STEPS[kind], current])
        raise VersionError(
            f"unknown {_LABELS[kind]} version {version}; this lpam reads version {known}",
            path=path, line=line, column=column, hint=f"write `version: {current}`",
        )
    return version


def _normalise(value: Any) -> str | None:
    """The version as comparable text, or None when it is not a version at all."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(float(value)) if math.isfinite(value) else None
    if isinstance(value, str) and _NUMBER.match(value.strip()):
        text = value.strip()
        return str(int(text)) if text.isdigit() else repr(float(text))
    return None


def _newer(version: str, current: int) -> bool:
    try:
        return float(version) > current
    except ValueError:
        return False
