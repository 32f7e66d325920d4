"""The status file a car publishes on the branch `status/<vehicle>` of its desired-state
repository (`status.json`), which `lpam fleet status` reads in any clone.

Version 2 adds `override`: a local edit the car runs instead of its fleet file
(migrations/car_status_v1_to_v2.py). A car that runs several apps (issue 22) adds `apps`,
every installed app, to a version 2 file: an optional field, absent (empty) in the files
of cars with one app or none, which stay exactly what they were — so an lpam from before
several apps still reads them, and `app` (the first installed app) keeps its meaning.

Version 3 adds `last_change`: the newest change the car's history records and who asked
for it (a phone, a user, the agent: issue 31), so the fleet sees who put an app in place
(migrations/car_status_v2_to_v3.py; a version-2 file names none: `null`).

Files published before version 1 carry no `version` (version 0): the same two parts, the
agent's status as that car's lpam wrote it (an agent status version 1 or 2) and the app;
migrations/car_status_v0_to_v1.py brings one to version 1. Written and read in one place,
reconciler/core/publication.py.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas.agent import AgentStatus
from schemas.override import LocalOverride
from schemas.record import Actor, ApplyResult


class PublishedApp(BaseModel):
    """What the fleet sees of a car's installed app (from `lpam status --json`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str | None = None
    generation: str | None = None
    status: str | None = Field(default=None, description="the app's status in the record")
    running: bool | None = None


class LastChange(BaseModel):
    """The newest change the car's history records (`lpam history`'s last set): when, what
    it made current, how it ended, and who asked for it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    time: str
    result: ApplyResult
    apps: list[str] = Field(default_factory=list, description="`app@generation` of each "
                            "app the change made current (or rolled back)")
    by: Actor | None = Field(default=None, description="who asked for it (None: not "
                             "recorded, a change made by an lpam before state record 8)")


class CarStatus(BaseModel):
    """One car's published status: its agent's and its app's (None: no app installed)."""

    model_config = ConfigDict(extra="forbid")

    version: Literal[3] = 3
    agent: AgentStatus
    app: PublishedApp | None = None
    override: LocalOverride | None = Field(
        default=None, description="a local edit (phone, libpanda-app-manager) the car runs "
        "instead of its fleet file, until it is released")
    apps: list[PublishedApp] = Field(
        default_factory=list, description="every installed app, in the order they were "
        "installed, when the car runs several (`app` is the first); empty: `app` alone "
        "says what runs")
    last_change: LastChange | None = Field(
        default=None, description="the newest change the car's history records, and who "
        "asked for it (None: no change recorded yet)")

    def installed(self) -> list[PublishedApp]:
        """Every app the car reported installed, whichever shape its file has."""
        if self.apps:
            return list(self.apps)
        return [] if self.app is None else [self.app]
