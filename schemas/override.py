"""A local override (`<root>/var/lib/lpam/override.json`): the desired state of a car that
follows a fleet repository was edited on the car itself — by a phone over Bluetooth or by
`libpanda-app-manager` — and the agent must not undo that edit on its next pass.

Why a document of its own: the override outlives the process that made it (the phone
disconnects, the car reboots), it is shown by `lpam status` and published in the car's
fleet status (schemas/fleet.py), and it ends only by an explicit act (the phone's update,
`lpam apply --release`). Version 1.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictStr


class LocalOverride(BaseModel):
    """Who overrode the fleet's desired state on this car, since when, and from which
    revision of the fleet's file the edited copy started."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[1] = 1
    since: StrictStr = Field(description="when the first local edit was applied (ISO 8601)")
    by: StrictStr = Field(description="what made the last edit: phone, libpanda-app-manager")
    edits: int = Field(default=1, ge=1, description="local edits applied since `since`")
    revision: StrictStr | None = Field(
        default=None, description="the fleet revision the car had applied when the override "
        "began (its file was the starting point of the local copy)")
    seeded: StrictBool = Field(
        default=False, description="the local desired-state file was made from the fleet's "
        "file by the override (and is set aside when the override ends)")
