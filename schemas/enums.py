"""Closed sets of strings, spelled the same on every Python lpam runs on.

`enum.StrEnum` arrived in Python 3.11; the vehicles run 3.9 (Raspberry Pi OS Bullseye).
This base gives what lpam relies on from it, identically on every version: members are
`str` (they compare equal to, and serialise as, their value) and `str()` and f-strings give
the value. A plain `class X(str, Enum)` would not: its `str()` is "X.MEMBER", and from 3.12
on its f-strings say so too (they follow `__str__`, overridden here).
"""

from __future__ import annotations

from enum import Enum


class StrEnum(str, Enum):
    """A string enumeration: `str(member)` and `f"{member}"` are the member's value."""

    def __str__(self) -> str:
        return str(self.value)

