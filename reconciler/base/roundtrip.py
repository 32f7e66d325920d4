"""Round-trip edits of a YAML document lpam rewrites for the user (`lpam pin`, the phone's
and `libpanda-app-manager`'s edits): the file keeps its comments, key order, quotes, line
widths and the way it indents a list's dash, so that what changed is only what was asked.

Why here and not in the callers: ruamel.yaml keeps the comment lines that follow a value
with the last scalar above them, so a naive replace, add or delete moves or loses them;
those rules are written once.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

# Imported inside functions: ruamel.yaml loads only when a document is edited (start-up:
# workflow/editing.py and workflow/pin.py import this module and stay ruamel-free).


def sequence_offset(text: str) -> int:
    """How far the file indents a list's dash under its key (`  - url:` is 2, `- url:` 0)."""
    found = re.search(r"^repositories:[ \t]*(?:#.*)?\n(?:[ \t]*(?:#.*)?\n)*([ \t]*)- ",
                      text, re.MULTILINE)
    return len(found.group(1)) if found else 2


def replace(tree: Any, key: str, value: Any) -> None:
    """`tree[key] = value`, the comment lines that followed the old value kept after the
    new one (ruamel keeps them with the last scalar above them: see `_cut_tail`)."""
    rest = _cut_tail(tree, key) if key in tree else None
    tree[key] = value
    if rest:
        _put_tail(tree, key, rest)


def add(node: Any, key: Any, value: Any) -> None:
    """A new last key of a mapping (`key`) or item of a sequence (`key` None), the comment
    lines that followed the old last one moved after it."""
    last = _last(node)
    rest = _cut_tail(node, last) if last is not None else None
    if key is None:
        node.append(value)
        key = len(node) - 1
    else:
        node[key] = value
    if rest:
        _put_tail(node, key, rest)


def drop(node: Any, key: Any) -> None:
    """`del node[key]`; were it the last, the comment lines after it follow the new last."""
    rest = _cut_tail(node, key) if key == _last(node) else None
    del node[key]
    last = _last(node)
    if rest and last is not None:
        _put_tail(node, last, rest)


def _last(node: Any) -> Any:
    if not node:
        return None
    return list(node)[-1] if isinstance(node, Mapping) else len(node) - 1


def _leaf(node: Any, key: Any) -> tuple[Any, Any]:
    """The container and key of the last scalar under `node[key]`; a flow collection
    (`{A: "1"}`, `[a, b]`) counts as one scalar: the comments after it are its key's."""
    while True:
        value = node[key]
        last = _last(value) if isinstance(value, (Mapping, list)) else None
        if last is None or not hasattr(value, "ca") or \
                (hasattr(value, "fa") and value.fa.flow_style()):
            return node, key
        node, key = value, last


def _cut_tail(node: Any, key: Any) -> str | None:
    """Take the whole comment lines that follow `node[key]` (kept by ruamel in the token
    after its last scalar, behind that line's own end-of-line comment, which stays)."""
    container, leaf = _leaf(node, key)
    slot = container.ca.items.get(leaf)
    at = 2 if isinstance(container, Mapping) else 0
    token = slot[at] if slot is not None and len(slot) > at else None
    if token is None:
        return None
    own, _, rest = str(token.value).partition("\n")
    if not rest.strip():
        return None
    if own.strip():
        token.value = own + "\n"
    else:
        slot[at] = None
    return rest


def _put_tail(node: Any, key: Any, rest: str) -> None:
    from ruamel.yaml.error import CommentMark
    from ruamel.yaml.tokens import CommentToken

    container, leaf = _leaf(node, key)
    mapping = isinstance(container, Mapping)
    slot = container.ca.items.setdefault(leaf, [None, None, None, None] if mapping
                                         else [None, None])
    at = 2 if mapping else 0
    if slot[at] is not None:  # its own end-of-line comment comes first
        slot[at].value = str(slot[at].value).rstrip("\n") + "\n" + rest
    else:
        slot[at] = CommentToken("\n" + rest, CommentMark(0), None)


def writer(text: str) -> Any:
    """A ruamel.yaml reader and writer in the style of `text` (a text `loading.load`
    already accepted): quotes kept, a list's dash indented as the file does, no line
    re-wrapped."""
    from ruamel.yaml import YAML

    yaml = YAML()
    yaml.preserve_quotes = True
    yaml.width = 4096
    offset = sequence_offset(text)
    yaml.indent(mapping=2, sequence=offset + 2, offset=offset)
    # `app: null` as the README writes it, not ruamel's bare `app:` (the same value, but
    # a reader of the file should not have to know YAML to see there is no app)
    yaml.representer.add_representer(type(None), _null)
    return yaml


def _null(representer: Any, data: None) -> Any:
    return representer.represent_scalar("tag:yaml.org,2002:null", "null")


def mapping(items: Mapping[str, Any]) -> Any:
    from ruamel.yaml.comments import CommentedMap

    return CommentedMap(items)


def sequence() -> Any:
    from ruamel.yaml.comments import CommentedSeq

    return CommentedSeq()
