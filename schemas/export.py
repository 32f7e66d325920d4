"""Export the JSON Schemas of lpam's documents to `schemas/json/`.

Editors and CI of a desired-state repository can validate against these files without
lpam. `python -m schemas.export` rewrites them; a test fails when they drift from the models.

An older version's schema stays, frozen: fleet repositories' editors reference
`desired-state.v1.schema.json` by name, and lpam still reads version 1 (through
migrations/), so their files are still right. No model renders it any more; `FROZEN`
holds its digest, and a test fails if the file is changed or removed.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from schemas.agent import AgentConfig, AgentStatus
from schemas.catalog import RawCatalog
from schemas.desired import DesiredState
from schemas.fleet import CarStatus
from schemas.generation import GenerationMeta
from schemas.override import LocalOverride
from schemas.plan import Plan
from schemas.record import StateRecord
from schemas.report import StatusReport
from schemas.timeline import Edge, Sidecar, Software

DOCUMENTS: dict[str, type[BaseModel]] = {
    "desired-state.v2.schema.json": DesiredState,
    "app-catalog.schema.json": RawCatalog,
    "state-record.v8.schema.json": StateRecord,
    "plan.v2.schema.json": Plan,
    "generation-meta.v1.schema.json": GenerationMeta,
    "agent.v1.schema.json": AgentConfig,
    "agent-status.v2.schema.json": AgentStatus,
    "car-status.v3.schema.json": CarStatus,
    "override.v1.schema.json": LocalOverride,
    "status-report.v1.schema.json": StatusReport,
    "timeline-edge.v1.schema.json": Edge,
    "timeline-software.v1.schema.json": Software,
    "provenance-sidecar.v1.schema.json": Sidecar,
}
FOLDER = Path(__file__).resolve().parent / "json"
FROZEN: dict[str, str] = {
    "desired-state.v1.schema.json":
        "2c13c0f032f457b405cd94c08cb115a65c9c29a713cb7278976f78589e00bdd8",
}
"""Schemas of versions lpam still reads but no longer writes: file name → SHA-256."""


def rendered() -> dict[str, str]:
    """File name → the exact text the model exports."""
    out = {}
    for name, model in DOCUMENTS.items():
        schema: dict[str, Any] = model.model_json_schema()
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        out[name] = json.dumps(schema, indent=2, sort_keys=True) + "\n"
    return out


def main() -> int:
    FOLDER.mkdir(exist_ok=True)
    for name, text in rendered().items():
        (FOLDER / name).write_text(text, encoding="utf-8")
        print(f"wrote {FOLDER / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
