"""The plan as a person reads it, in Terraform's manner: `+ ~ - -/+` and a summary line."""

from __future__ import annotations

from reconciler.core.planning.model import UNKNOWN
from schemas.plan import Action, Plan

_ORDER = ("name", "repository", "url", "ref", "commit", "generation", "params", "status")


def _value(value: object) -> str:
    if value is None:
        return "null"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}={v}" for k, v in sorted(value.items())) + "}"
    return str(value)


def render(plan: Plan, *, show_noop: bool = False) -> str:
    lines: list[str] = []
    for change in plan.changes:
        if change.action is Action.NOOP and not show_noop:
            for warning in change.warnings:
                lines.append(f"  ! {change.address}: {warning}")
            continue
        symbol = change.action.symbol
        lines.append(f"{symbol:>3} {change.address}: {change.reason}")
        before, after = change.before or {}, change.after or {}
        for key in _ORDER:
            if key not in before and key not in after:
                continue
            old, new = before.get(key), after.get(key)
            if change.action is Action.CREATE or not before:
                lines.append(f"        {key} = {_value(new)}")
            elif change.action is Action.DELETE or not after:
                lines.append(f"        {key} = {_value(old)}")
            elif key in after and old != new:
                lines.append(f"        {key}: {_value(old)} → {_value(new)}")
        for warning in change.warnings:
            lines.append(f"      ! {warning}")
    if plan.steps:
        lines.append("")
        lines.append("Steps:")
        for number, step in enumerate(plan.steps, 1):
            lines.append(f"  {number:>2}. [{step.phase.value}] {step.id}")
    lines.append("")
    if plan.offline:
        lines.append("Offline plan: branches and tags as of the last fetch; values marked "
                     f"{UNKNOWN!r} need the network. Run `lpam plan` for an exact plan.")
    lines.append(plan.summary)
    return "\n".join(lines).lstrip("\n")
