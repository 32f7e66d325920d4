"""JSON documents lpam wrote itself — the state record, saved plans, the override, the
agent's status — read by `json` and validated, with every fault at file:line:column.

These documents are read on every command (`lpam status` and every plan read the state
record), and they are almost always sound: so the sound path is `json.loads`, the
migrations and pydantic, and nothing more. The YAML reader, which keeps positions, is
imported and run only once a fault needs a line and column. This module imports no model
of the YAML documents (desired state, catalog, agent settings) nor the plan's, so reading
the record costs only the record's own model (issue 32 item 2: core/documents.py, where
this lived, imported them all for every read of the record).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from reconciler.base.errors import ConfigError
from schemas.kinds import DocumentKind

if TYPE_CHECKING:
    from pydantic import BaseModel

    from reconciler.base.loading import Document


M = TypeVar("M", bound="BaseModel")


def parse_json(
    kind: DocumentKind, text: str, path: Path, model: type[M], *, hint: str,
    version_key: str = "version",
) -> M:
    """A JSON document lpam wrote itself (plan, state record): parse, migrate, validate.

    A fault names its line and column like a YAML document's: JSON is YAML, so the text is
    parsed again for positions, but only once a fault needs them (a large plan is parsed
    once, by `json`, when it is sound).
    """
    from pydantic import ValidationError

    from migrations import upgrade

    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"not a valid {kind}: {exc.msg}", path=path, line=exc.lineno,
                          column=exc.colno, hint=hint) from None
    except RecursionError:
        raise ConfigError(f"not a valid {kind}: nested too deeply", path=path, line=1,
                          column=1, hint=hint) from None
    where = JsonPositions(path, text, version_key)
    if isinstance(data, dict) and version_key != "version" and version_key in data:
        data["version"] = data.pop(version_key)
    data = upgrade(kind, data, path=path, position=where)
    if version_key != "version":
        data[version_key] = data.pop("version")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        error = exc.errors()[0]
        loc, message = _tagged(data, list(error["loc"])), str(error["msg"])
        if error["type"] == "union_tag_invalid":  # pydantic lists the tags as reprs
            loc, message = [*loc, "kind"], f"unknown kind {error['ctx']['tag']!r}"
        field = ".".join(str(p) for p in loc)
        line, column = where(loc)
        raise ConfigError(f"invalid {kind} at {field}: {message}", path=path,
                          line=line, column=column, hint=hint) from None


def _tagged(data: Any, loc: list[str | int]) -> list[str | int]:
    """`loc` without the tags pydantic inserts for a union chosen by `kind` (a plan's
    steps: `steps.0.install.app` is `steps.0.app` in the document)."""
    kept: list[str | int] = []
    node = data
    for part in loc:
        if isinstance(node, dict) and part not in node and node.get("kind") == part:
            continue
        kept.append(part)
        node = node.get(part) if isinstance(node, dict) else (
            node[part] if isinstance(node, list) and isinstance(part, int)
            and 0 <= part < len(node) else None)
    return kept


class JsonPositions:
    """1-based (line, column) of a location in a JSON text, parsed as YAML on first use.
    A text the YAML reader refuses (a plan of more values than a YAML document may hold)
    has no positions: its faults name the field only."""

    def __init__(self, path: Path, text: str, version_key: str) -> None:
        self._path, self._text, self._version_key = path, text, version_key
        self._doc: Document | None = None
        self._failed = False

    def __call__(self, loc: Sequence[str | int]) -> tuple[int, int] | tuple[None, None]:
        if self._doc is None and not self._failed:
            from reconciler.base.loading import load

            try:
                self._doc = load(self._path, self._text)
            except ConfigError:
                self._failed = True
        if self._doc is None:
            return None, None
        # `version` is the migrations' name of the plan's `format_version`
        loc = [self._version_key if part == "version" else part for part in loc]
        return self._doc.position([p for p in loc if isinstance(p, (str, int))])
