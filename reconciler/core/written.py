"""JSON documents lpam wrote itself — the state record, saved plans, the override, the
agent's status — read by `json` and validated, with every fault at file:line:column.

These documents are read on every command (`lpam status` and every plan read the state
record), and they are almost always sound: so the sound path is `json.loads`, the
migrations and pydantic, and nothing more. A fault's line and column are worked out only
once there is a fault, and by `json` too (`json_position`), never by the YAML reader:
composing a record through it cost more than all the rest of reading it, and it refuses
large documents `json` reads (issue 32 item 2). This module imports no model of the YAML
documents (desired state, catalog, agent settings) nor the plan's, so reading the record
costs only the record's own model (core/documents.py, where this lived, imported them
all for every read of the record).
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from reconciler.base.errors import ConfigError
from schemas.kinds import DocumentKind

if TYPE_CHECKING:
    from pydantic import BaseModel

# Imported inside functions: pydantic and the migrations load only when JSON is parsed into a
# model; its importers (documents, validation, state) load pydantic anyway: little gain.


M = TypeVar("M", bound="BaseModel")


def parse_json(
    kind: DocumentKind, text: str, path: Path, model: type[M], *, hint: str,
    version_key: str = "version",
) -> M:
    """A JSON document lpam wrote itself (plan, state record): parse, migrate, validate.

    A fault names its line and column like a YAML document's: a syntax error where `json`
    reports it, a fault the migrations or the model find where `json_position` places it,
    worked out only then.
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
    where = JsonPositions(text, version_key)
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
    """1-based (line, column) of a location in a JSON text, found by `json_position` once a
    fault asks for it; (None, None) where the text has no such place."""

    def __init__(self, text: str, version_key: str) -> None:
        self._text, self._version_key = text, version_key

    def __call__(self, loc: Sequence[str | int]) -> tuple[int, int] | tuple[None, None]:
        # `version` is the migrations' name of the plan's `format_version`
        return json_position(self._text, [self._version_key if part == "version" else part
                                          for part in loc])


_BLANK = re.compile(r"[ \t\n\r]*")
_DECODER = json.JSONDecoder()


def json_position(text: str, loc: Sequence[str | int]) -> tuple[int, int] | tuple[None, None]:
    """Where `loc` is written in the JSON `text`, as the YAML reader places a node (what a
    fault in a YAML document names, so both kinds of document name it alike): a key where
    it is written, an item where it starts, and for a location that is not there the
    deepest part of it that is (a missing key: the mapping it is missing from).

    The text is walked with `json`'s own decoder, skipping the values beside the path (in
    C), so a fault in a record or plan of any size is placed without the YAML reader: it
    refuses what `json` reads (more values than a YAML document may hold, a lone
    surrogate), and composing a large record through it cost seconds on a Pi. A key
    written twice is placed at its last occurrence, the one `json` keeps. (None, None)
    for a text `json` does not read (it never reaches here: it is refused first, at the
    place `json` names).
    """
    try:
        at = index = _skip(text, 0)
        for part in loc:
            found = _member(text, index, part)
            if found is None:
                break
            at, index = found
    except (ValueError, IndexError, RecursionError):
        return None, None
    line = text.count("\n", 0, at) + 1
    return line, at - (text.rfind("\n", 0, at) + 1) + 1


def _member(text: str, index: int, part: str | int) -> tuple[int, int] | None:
    """(where `part` is written, where its value starts) in the object or array at `index`;
    None when that value is neither, or has no such member."""
    opening = text[index]
    if opening == "{" and isinstance(part, str):
        found = None
        index = _skip(text, index + 1)
        while text[index] == '"':
            key, after = _DECODER.raw_decode(text, index)
            value = _skip(text, _skip(text, after) + 1)  # past the `:`
            if key == part:
                found = (index, value)
            index = _next(text, value)
        return found
    if opening == "[" and isinstance(part, int) and not isinstance(part, bool) and part >= 0:
        index = _skip(text, index + 1)
        count = 0
        while text[index] != "]":
            if count == part:
                return index, index
            index = _next(text, index)
            count += 1
    return None


def _skip(text: str, index: int) -> int:
    """Past the blanks JSON allows between tokens."""
    blank = _BLANK.match(text, index)
    return blank.end() if blank is not None else index


def _next(text: str, value: int) -> int:
    """Past the value at `value` and its `,`: the next member's start, or the closing
    bracket's index."""
    _, end = _DECODER.raw_decode(text, value)
    end = _skip(text, end)
    return _skip(text, end + 1) if text[end] == "," else end
