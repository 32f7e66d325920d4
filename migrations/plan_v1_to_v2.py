"""Plan 1 → 2: each kind of step typed, instead of string arguments parsed when it runs.

Why: version 1 wrote every step's arguments as one mapping of strings (`args`): health
numbers and CAN ids as text, `good: "yes"`, a stray as `stray: "yes"`, so a missing or
mistyped argument was only found when the step ran — possibly mid-cutover. Version 2
gives each kind its own fields (schemas/plan.py), checked when the plan is loaded.

The fingerprint: a version-1 plan was sealed over its version-1 body. That seal is
checked here, on the body as it was written, *before* anything is carried forward (an
edited version-1 plan is refused, located at its `fingerprint`); the version-2 body this
step returns is then sealed again by the same rule, so the loaded plan's fingerprint
matches its typed steps. A plan whose seal does not match is never re-sealed.

This step is frozen: it writes every field of version 2 itself (defaults included, as the
version-2 models dump them), so the seal it computes is the one a version-2 lpam computes.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from migrations.step import MigrationError

_APP_KINDS = ("stage", "install", "configure", "start")
_PLAIN = {"checkout": ("key", "url", "ref", "commit"), "remove": ("key",),
          "apt": ("app", "packages"), "pip": ("app", "requirements"),
          "build": ("app", "build", "workspace", "user", "ros", "ros_keys", "ros_urls")}
_OPTIONAL = {"ref", "commit"}  # a checkout's: absent or null in an offline plan


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Check the version-1 seal, type every step, seal the result as version 2."""
    if doc.get("fingerprint") != _seal(_body(doc, 1, doc.get("steps"))):
        raise MigrationError("the plan's fingerprint does not match its steps (edited or "
                             "corrupt)", loc=("fingerprint",),
                             hint="make a new plan with `lpam plan --out FILE`")
    steps = [typed_step(item, index) for index, item in enumerate(doc.get("steps") or [])]
    return dict(doc, version=2, steps=steps, fingerprint=_seal(_body(doc, 2, steps)))


def _body(doc: dict[str, Any], version: int, steps: Any) -> dict[str, Any]:
    return {"format_version": version, "offline": doc.get("offline", False),
            "lineage": doc.get("lineage"), "serial": doc.get("serial"), "steps": steps}


def _seal(body: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


def typed_step(item: Any, index: int) -> dict[str, Any]:
    """One version-1 step (`id`, `kind`, `phase`, `args`, `needs`) in version 2."""
    try:
        kind, args = item["kind"], item["args"]
        fields = _typed(kind, args)
        return {"id": item["id"], "kind": kind, "phase": item["phase"],
                "needs": list(item.get("needs") or []), **fields}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise MigrationError(f"step {index + 1} of the version-1 plan cannot be carried "
                             f"forward ({type(exc).__name__}: {exc})", loc=("steps", index),
                             hint="make a new plan with `lpam plan --out FILE`") from None


def _typed(kind: str, args: dict[str, Any]) -> dict[str, Any]:
    if kind in _PLAIN:
        return {name: args.get(name) if name in _OPTIONAL else args[name]
                for name in _PLAIN[kind]}
    if kind in _APP_KINDS:
        return {"app": _generation(args), "good": args.get("good") == "yes"}
    if kind == "verify":
        return {"app": _generation(args), "health": _health(args)}
    if kind in ("stop", "uninstall"):
        if args.get("stray"):
            stray = {"name": args["app"], "generation": args["generation"],
                     "params": dict(args.get("params") or {})}
            return {"app": None, "stray": stray}
        return {"app": _generation(args), "stray": None}
    if kind == "adopt":
        return {"app": _generation(args), "folder": args["folder"],
                "running": args.get("running") == "yes"}
    raise ValueError(f"unknown kind {kind!r}")


def _generation(args: dict[str, Any]) -> dict[str, Any]:
    """The app as version 1 spelt it (`app`, `build`), every field of version 2 given."""
    return {
        "name": args["app"], "generation": args["generation"],
        "repository": args["repository"], "commit": args.get("commit"),
        "path": args.get("path"), "tree": args.get("tree"),
        "params": dict(args.get("params") or {}), "service": args.get("service"),
        "command": args.get("command"), "launch": args.get("launch"), "user": args.get("user"),
        "pip": list(args.get("pip") or []), "ros": dict(args.get("ros") or {}),
        "ros_build": args.get("build"), "ros_workspace": args.get("ros_workspace"),
        "ros_user": args.get("ros_user"),
    }


def _health(args: dict[str, Any]) -> dict[str, Any]:
    """Version 1's health texts as numbers; a missing value took the runner's default."""
    settings = args.get("health") or {}
    can = args.get("health_can") or {}
    return {
        "settle_seconds": float(settings.get("settle_seconds", "0")),
        "timeout_seconds": float(settings.get("timeout_seconds", "10")),
        "command": args.get("health_command"),
        "can_ids": [int(text, 16) for text in (can.get("ids") or "").split()],
        "can_within_seconds": float(can.get("within_seconds", "10")),
    }
