"""Exclusive resources: which desired apps cannot run side by side.

A car's panda (its CAN interface), a serial GPS or a shared unit such as `can` may have
one owner at a time; two controllers both writing to the bus is the fault lpam exists to
prevent. Each desired app claims resources (its catalog's `resources:`, `panda` for
`owns_panda: true`, `service:<unit>` for the unit its `service` file names:
reconciler/engine/observe/targets.py fills `AppTarget.resources`). Before anything changes, the
claims of every desired app are checked here: two apps claiming one resource are refused
with both apps' positions in the desired state, so the user goes straight to the entries
to fix.

Pure: claims in, conflicts or owners out. The order of the input (the desired state's
order of apps) decides which app is "first" and which is refused, so every answer is
the same for the same document.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from reconciler.base.errors import ConfigError, place
from schemas.catalog import SERVICE_PREFIX


class Where(NamedTuple):
    """An app entry's position in the document that desires it (1-based, as editors)."""

    path: Path
    line: int | None = None
    column: int | None = None

    def __str__(self) -> str:
        return place(self.path, self.line, self.column)


@dataclass(frozen=True)
class Claim:
    """One desired app, where it is desired, and the exclusive resources it claims."""

    app: str
    where: Where
    resources: frozenset[str]


@dataclass(frozen=True)
class Conflict:
    """A resource two or more apps claim, with their claims in the desired order."""

    resource: str
    claims: tuple[Claim, ...]

    @property
    def apps(self) -> tuple[str, ...]:
        return tuple(claim.app for claim in self.claims)


def conflicts(claims: Iterable[Claim]) -> list[Conflict]:
    """Every resource with more than one claiming app, sorted by resource. An app claims
    a resource once however often it is listed (it cannot be its own rival)."""
    by_resource: dict[str, list[Claim]] = {}
    for claim in claims:
        for resource in claim.resources:
            holders = by_resource.setdefault(resource, [])
            if all(held.app != claim.app for held in holders):
                holders.append(claim)
    return [Conflict(resource, tuple(holders))
            for resource, holders in sorted(by_resource.items()) if len(holders) > 1]


def refuse(found: list[Conflict]) -> None:
    """Raise the ConfigError that refuses the first conflict (by resource), located at its
    second app (the one that cannot also have it) and naming the first; nothing to do
    without conflicts."""
    if not found:
        return
    conflict = found[0]
    second = conflict.claims[1]
    rivals = [f"{c.app} ({c.where})" for c in conflict.claims if c is not second]
    named = f"app {rivals[0]} claims" if len(rivals) == 1 else \
        f"apps {', '.join(rivals[:-1])} and {rivals[-1]} claim"
    more = f"; {len(found) - 1} more resource(s) are claimed twice: " \
        f"{', '.join(c.resource for c in found[1:])}" if len(found) > 1 else ""
    raise ConfigError(
        f"app {second.app} claims the exclusive resource {_named(conflict.resource)}, which "
        f"{named} too; one owner at a time{more}",
        path=second.where.path, line=second.where.line, column=second.where.column,
        hint=_hint(conflict.resource),
    )


def owners(claims: Iterable[Claim]) -> dict[str, str]:
    """Resource → the one app that claims it, sorted by resource (the cutover orders each
    resource's old owner's stop before its new owner's start). Refused like `refuse` when
    a resource has two claimants: an owner is never a guess."""
    claims = list(claims)
    refuse(conflicts(claims))
    found = {resource: claim.app for claim in claims for resource in claim.resources}
    return dict(sorted(found.items()))


def _named(resource: str) -> str:
    if resource.startswith(SERVICE_PREFIX):
        return f"{resource} (each names the unit {resource[len(SERVICE_PREFIX):]} in its " \
            "`service` file)"
    return resource


def _hint(resource: str) -> str:
    if resource.startswith(SERVICE_PREFIX):
        return "keep one of these apps in the desired state; two apps cannot both " \
            "start and stop one unit"
    return "keep one of these apps in the desired state, or give them different " \
        "resources in their catalogs (libpanda-apps.yaml `resources:`)"
