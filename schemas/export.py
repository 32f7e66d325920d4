"""Export the JSON Schemas of lpam's documents to `schemas/json/`.

Editors and CI of a desired-state repository can validate against these files without
lpam. `python -m schemas.export` rewrites them; a test fails when they drift from the models.
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

DOCUMENTS: dict[str, type[BaseModel]] = {
    "desired-state.v1.schema.json": DesiredState,
    "app-catalog.schema.json": RawCatalog,
    "state-record.v4.schema.json": StateRecord,
    "plan.v2.schema.json": Plan,
    "generation-meta.v1.schema.json": GenerationMeta,
    "agent.v1.schema.json": AgentConfig,
    "agent-status.v2.schema.json": AgentStatus,
    "car-status.v2.schema.json": CarStatus,
    "override.v1.schema.json": LocalOverride,
}
FOLDER = Path(__file__).resolve().parent / "json"


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
