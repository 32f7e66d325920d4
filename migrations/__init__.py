"""Versioned documents: bring what lpam reads up to the version this lpam understands.

Every document lpam reads carries a `version`. Between loading (YAML/JSON → plain data)
and validation (pydantic models in `schemas/`), `upgrade` applies the step functions of
this package one after the other, each a pure `dict -> dict` in its own module with
before/after fixtures in `fixtures/` (Terraform's `states/statefile/version*_upgrade`).
A document from a *newer* lpam is refused by name rather than half-understood: the
operator must upgrade lpam, not lose fields silently.

The registry (`CURRENT`, `STEPS`, `upgrade`) lives in registry.py and is named here, so
callers write `from migrations import upgrade`; what every step shares is in step.py.
"""

from __future__ import annotations

from migrations.registry import CURRENT, STEPS, upgrade

__all__ = ["CURRENT", "STEPS", "upgrade"]
