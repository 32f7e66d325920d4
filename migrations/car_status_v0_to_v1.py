"""Car status 0 → 1: the file a car publishes on `status/<vehicle>` gets a `version`.

Why: the file had no version, so `lpam fleet status` read whatever a car's lpam wrote key
by key and could not tell an older car's file from a damaged one. Version 1 is a typed
document (schemas/fleet.py). The shape is the same; what a version-0 file holds inside is
the agent status as that car's lpam wrote it, version 1 or 2, and this step brings a
version-1 agent status to version 2 (migrations/agent_status_v1_to_v2.py), so that the
whole file is read by one model.
"""

from __future__ import annotations

from typing import Any

from migrations.agent_status_v1_to_v2 import upgrade as upgrade_agent_status
from migrations.step import MigrationError


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Add `version: 1`; an agent status version 1 inside becomes version 2."""
    agent = doc.get("agent")
    if not isinstance(agent, dict):
        raise MigrationError("`agent` must be the agent's status", loc=("agent",),
                             hint="the car publishes a new one with its next status")
    if agent.get("version") == 1:
        try:
            agent = upgrade_agent_status(agent)
        except MigrationError as exc:
            raise MigrationError(exc.message, loc=("agent", *exc.loc), hint=exc.hint) from None
    return dict(doc, version=1, agent=agent)
