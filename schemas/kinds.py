"""Closed sets lpam decides on, beside the documents that name them.

A service manager and a document kind are chosen by name (a flag, an environment variable,
a document's own key) and then branched on: as enums, a misspelt name is refused where it
is read and every branch is checked by mypy, instead of a string that silently matches
nothing (issue 20).
"""

from __future__ import annotations

from schemas.enums import StrEnum


class ServiceKind(StrEnum):
    """The service manager that runs the apps (reconciler/adapters/services/choice.py)."""

    SYSTEMD = "systemd"  # the vehicle's init
    SUPERVISOR = "supervisor"  # supervisord, which lpam starts itself where systemd does not run


class DocumentKind(StrEnum):
    """Every versioned document lpam reads, as migrations/ knows it."""

    DESIRED_STATE = "desired-state"
    STATE_RECORD = "state-record"
    PLAN = "plan"
    AGENT_CONFIG = "agent-config"
    AGENT_STATUS = "agent-status"
    GENERATION_META = "generation-meta"
    CAR_STATUS = "car-status"
    OVERRIDE = "override"
    TIMELINE = "timeline"
