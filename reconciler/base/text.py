"""Text from outside (files, processes, servers, the user) made safe to show on one line.

A terminal interprets control characters (an escape sequence can rewrite the screen, a
carriage return hide what came before it), and a value can be megabytes long: what lpam
echoes goes through here; `columns` lines such text up in a table. Pure, and imports
nothing of lpam, so every layer may use it.
"""

from __future__ import annotations

from collections.abc import Sequence

MESSAGE_LIMIT = 400


def printable(text: str, replacement: str = "?") -> str:
    """`text` with each character a terminal would interpret replaced by `replacement`."""
    return "".join(c if c.isprintable() else replacement for c in text)


def escaped(text: str) -> str:
    """`text` with each such character written as its Python escape (`\\x1b`): shown,
    never interpreted, and still telling which character it was."""
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)


def shorten(text: str, limit: int = MESSAGE_LIMIT) -> str:
    """`text` cut in the middle to at most about `limit` characters: a message that echoes
    a 900 KB value must still be one readable line."""
    if len(text) <= limit:
        return text
    keep = max(limit - 20, 20)
    return f"{text[: keep * 3 // 4]} … ({len(text) - keep} characters left out) … " \
        f"{text[len(text) - keep // 4:]}"


def counted(number: int, noun: str, plural: str | None = None) -> str:
    """`number noun`, the noun in the plural unless there is one: "1 app", "2 apps",
    "1 repository" — never "1 apps"."""
    return f"{number} {noun if number == 1 else plural or noun + 's'}"


def columns(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """The lines of a table: each column as wide as its widest cell, two spaces between
    columns, no trailing spaces (`lpam status`, `lpam fleet status`)."""
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(header)]
    return ["  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip()
            for row in [header, *rows]]
