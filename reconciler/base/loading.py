"""YAML in and out: every document lpam reads passes through here.

Reading keeps ruamel.yaml's round-trip tree beside the plain data, so that a later
validation error deep inside the document can still be reported at its line and column.
Writing goes through the same round-trip emitter, so comments a user put into a desired
state survive when lpam rewrites it (import, demo switch).
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from reconciler.base.errors import ConfigError
from reconciler.base.reading import read_bounded
from reconciler.base.text import shorten

# Imported inside functions: ruamel.yaml loads only when YAML is read or written (start-up: `lpam
# status` of an empty root loads no ruamel; tests/integration/test_imports.py).

MAX_DOCUMENT_BYTES = 1024 * 1024
MAX_DEPTH = 64
"""Nesting deeper than this is refused as the parser meets it: lpam's documents are a few
levels deep, and ruamel.yaml's composer recurses once per level (a document nested
100,000 deep exhausted Python's stack)."""
MAX_VALUES = 5000
"""More scalars than this is refused as the parser meets them: a desired state holds tens,
the field's largest catalog a few hundred, and ruamel.yaml's round-trip parser takes about
0.1 ms per value (a 60,000-key document took 17 s to be refused)."""
_SURROGATES = re.compile("[\ud800-\udfff]")


class _Refused(Exception):
    """Raised by the event guard inside ruamel.yaml; turned into a ConfigError by `load`."""

    def __init__(self, message: str, mark: Any, hint: str) -> None:
        super().__init__(message)
        self.message, self.mark, self.hint = message, mark, hint


@dataclass(frozen=True)
class Document:
    """A parsed YAML document: plain data for the code, the tree for positions."""

    path: Path
    data: Any
    tree: Any

    def position(self, loc: Iterable[str | int]) -> tuple[int, int]:
        """1-based (line, column) of the node at `loc`, or of its nearest existing parent."""
        return locate(self.tree, loc)

    def error(
        self, message: str, loc: Iterable[str | int] = (), hint: str | None = None
    ) -> ConfigError:
        line, column = self.position(loc)
        return ConfigError(message, path=self.path, line=line, column=column, hint=hint)


def _guarded_parser() -> type:
    """ruamel.yaml's round-trip parser, with every event checked as the composer takes it.

    One pass, before anything is built: what lpam's documents never need and ruamel.yaml
    would misread or crash on is refused at its line and column — explicit tags (`!!bool
    ex` crashed the constructor, `!!set` and `!foo` built values no schema expects),
    anchors and aliases (a self-referencing alias was read as null), lone surrogates
    (they passed validation and crashed later, when written as UTF-8), and nesting past
    MAX_DEPTH, or more than MAX_VALUES values.
    """
    from ruamel.yaml import events
    from ruamel.yaml.parser import RoundTripParser

    class GuardedParser(RoundTripParser):
        depth = 0
        values = 0

        def get_event(self) -> Any:
            event = super().get_event()
            mark = event.start_mark
            if isinstance(event, events.AliasEvent) or getattr(event, "anchor", None):
                raise _Refused("YAML anchors and aliases (&name, *name) are not supported",
                               mark, "write the value out in full where it is needed")
            if getattr(event, "tag", None) is not None:
                tag = str(event.tag).replace("tag:yaml.org,2002:", "!!")
                raise _Refused(f"YAML tags ({shorten(tag, 40)}) are not supported",
                               mark, "remove the tag; quote the value if it must be a string")
            if isinstance(event, events.ScalarEvent):
                self.values += 1
                if self.values > MAX_VALUES:
                    raise _Refused(f"the document holds more than {MAX_VALUES} values", mark,
                                   "lpam's documents hold tens of values; is it the right "
                                   "file?")
                if _SURROGATES.search(event.value):
                    raise _Refused("the text contains a lone surrogate (an invalid \\uD800-"
                                   "\\uDFFF escape)", mark, "write the character itself, or "
                                   "escape it as one \\U00XXXXXX code point")
            if isinstance(event, events.CollectionStartEvent):
                self.depth += 1
                if self.depth > MAX_DEPTH:
                    raise _Refused(f"the document is nested more than {MAX_DEPTH} levels deep",
                                   mark, "lpam's documents are a few levels deep; is it the "
                                   "right file?")
            elif isinstance(event, events.CollectionEndEvent):
                self.depth -= 1
            return event

    return GuardedParser


def _yaml(typ: str = "rt", *, keep_quotes: bool = False) -> Any:
    from ruamel.yaml import YAML

    yaml = YAML(typ=typ)
    yaml.allow_duplicate_keys = False
    yaml.preserve_quotes = keep_quotes
    if typ == "rt":
        yaml.Parser = _guarded_parser()
    return yaml


_DIRECTIVE = re.compile(r"^%(YAML|TAG)\b", re.MULTILINE)


def read_text(path: Path) -> str:
    """Read a document as UTF-8 text; empty, huge, binary or unreadable files are errors."""
    try:
        raw = read_bounded(path, limit=MAX_DOCUMENT_BYTES, what="the document",
                           hint="point lpam at the YAML document itself")
    except FileNotFoundError:
        raise ConfigError(
            "file not found", path=path, hint="check the path, or pass -f FILE"
        ) from None
    if b"\x00" in raw:
        raise ConfigError(
            "file is binary, not YAML text", path=path, line=1, column=1,
            hint="point lpam at the YAML document itself",
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(
            "file is not UTF-8 text", path=path, line=line, column=1,
            hint="save the file as UTF-8",
        ) from None
    if not text.strip():
        raise ConfigError(
            "file is empty", path=path, line=1, column=1,
            hint="start from desired-state.example.yaml",
        )
    return text


def load(path: Path, text: str | None = None, *, keep_quotes: bool = False) -> Document:
    """Parse one YAML document, turning every parser complaint into a ConfigError.

    `keep_quotes`: the tree keeps each scalar's quotes, as `roundtrip.writer` reads a file
    it rewrites, so that an edit (`lpam pin`, the phone's) changes the tree validated here
    instead of composing the same text a second time."""
    from ruamel.yaml.error import MarkedYAMLError, YAMLError

    if text is None:
        text = read_text(path)
    directive = _DIRECTIVE.search(text)
    if directive is not None:
        raise ConfigError(
            f"YAML directives (%{directive.group(1)}) are not supported", path=path,
            line=text.count("\n", 0, directive.start()) + 1, column=1,
            hint="remove the line; lpam reads YAML 1.2",
        )
    try:
        tree = _yaml(keep_quotes=keep_quotes).load(text)
    except _Refused as exc:
        raise ConfigError(exc.message, path=path, line=exc.mark.line + 1,
                          column=exc.mark.column + 1, hint=exc.hint) from None
    except RecursionError:  # a safety net: the guard stops nesting long before this
        raise ConfigError(f"the document is nested more than {MAX_DEPTH} levels deep",
                          path=path, line=1, column=1) from None
    except MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or "invalid YAML"
        hint = "fix the YAML syntax at that spot"
        if "\\t" in problem or "'\\t'" in problem or "tab" in problem.lower():
            problem, hint = "tab character used for indentation", "indent with spaces, not tabs"
        elif "duplicate key" in problem:
            problem = problem.split(" with value")[0]
            hint = "each key may appear once in a mapping; remove or merge the repeated one"
        line = mark.line + 1 if mark is not None else None
        column = mark.column + 1 if mark is not None else None
        raise ConfigError(problem, path=path, line=line, column=column, hint=hint) from None
    except YAMLError as exc:
        raise ConfigError(f"not valid YAML: {exc}", path=path, line=1, column=1) from None
    return Document(path=path, data=plain(tree, path), tree=tree)


MAX_NODES = 100_000


def plain(node: Any, path: Path | None = None) -> Any:
    """The round-trip tree as plain dicts, lists and scalars (what migrations work on).

    YAML aliases are expanded, so a self-referencing alias or an alias bomb ("billion
    laughs") would recurse forever or explode in memory: both are refused.
    """
    budget = [MAX_NODES]
    active: set[int] = set()

    def walk(item: Any) -> Any:
        budget[0] -= 1
        if budget[0] < 0:
            raise ConfigError(
                f"document expands to more than {MAX_NODES} nodes (YAML aliases?)",
                path=path, line=1, column=1, hint="write the values out instead of aliasing",
            )
        if isinstance(item, (Mapping, list)):
            if id(item) in active:
                line, column = locate(item, ())
                raise ConfigError("a YAML alias refers to itself", path=path, line=line,
                                  column=column, hint="remove the recursive alias")
            active.add(id(item))
            try:
                if isinstance(item, Mapping):
                    return {k if isinstance(k, str) else str(k): walk(v) for k, v in item.items()}
                return [walk(v) for v in item]
            finally:
                active.discard(id(item))
        if isinstance(item, str):
            return str(item)
        return item

    return walk(node)


def locate(tree: Any, loc: Iterable[str | int]) -> tuple[int, int]:
    """Walk `loc` through the round-trip tree; return the deepest known 1-based position."""
    line, column = 1, 1
    lc = getattr(tree, "lc", None)
    # A bare top-level scalar (such as `=`, which ruamel reads as a tagged value) has
    # an `lc` whose line is None: keep the document's start then.
    if lc is not None and lc.line is not None and lc.col is not None:
        line, column = lc.line + 1, lc.col + 1
    node = tree
    for part in loc:
        lc = getattr(node, "lc", None)
        try:
            if isinstance(node, Mapping) and part in node:
                at = lc.key(part) if lc is not None else None
            elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
                at = lc.item(part) if lc is not None else None
            else:
                break
            if at is not None:
                line, column = at[0] + 1, at[1] + 1
            node = node[part]
        except (KeyError, TypeError, AttributeError):
            break
    return line, column


def dump(data: Any, *, header: str | None = None) -> str:
    """Emit YAML (round-trip style); `header` lines become a leading comment block."""
    stream = io.StringIO()
    if header:
        for line in header.splitlines():
            stream.write(f"# {line}".rstrip() + "\n")
    yaml = _yaml()
    yaml.indent(mapping=2, sequence=4, offset=2)
    yaml.dump(data, stream)
    return stream.getvalue()
