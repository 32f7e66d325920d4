"""The timeline: what ran on this car, and when, as lpam saw it (issue 33, provenance).

A researcher's question starts from the data — *which controller, at which commit, with
which parameters, ran while this CAN log was recorded?* — so lpam keeps, per car, an
append-only list of `Edge`s: an app generation began or ended running, a running unit was
restarted by its service manager, or the wall clock was seen to jump. The intervals and
their certainty are derived from the edges (reconciler/core/provenance.py), never written:
a power cut can only lose a line, never leave an interval that says more than was known.

Each edge carries a `Stamp`: the boot it happened in (the kernel's boot id), the seconds
since that boot (CLOCK_BOOTTIME, which counts suspend and is never set) and the wall clock.
A Pi has no real-time clock: until GPS sets the time, its wall clock is the last
shutdown's, hours off. Within one boot, wall - boottime is constant unless the clock was
set, so a later stamp of the same boot corrects every earlier one.

What ran is a `Software`: the generation's repositories at their commits, its tree, its
parameters (and their digest, which the app's environment carries too), its dependencies
as installed, lpam's version and the desired state it came from. It is stored once per
distinct content (its `digest` names it) and edges name it, so a month of drives costs
lines of a few hundred bytes, not a pip freeze each.
"""

from __future__ import annotations

import hashlib
import json
from datetime import datetime, timezone
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

TIMELINE_VERSION: Literal[1] = 1

EdgeKind = Literal["began", "ended", "restarted", "clock"]
"""began/ended: an app generation started or stopped running; restarted: its unit was
restarted by the service manager (a crash or an exit) and runs again; clock: the wall
clock was seen to differ from the boot's earlier stamps (it was set: GPS, NTP)."""

How = Literal[
    "apply",  # an apply's cutover (or its first install) started or stopped it
    "rollback",  # an apply's automatic rollback, or `lpam rollback`
    "operator",  # `lpam stop|start`, libpanda-app-manager -s/-t, the phone
    "exited",  # seen stopped by its service manager without lpam stopping it
    "crashed",  # seen restarted by its service manager (a new process)
    "power-lost",  # found running in an earlier boot: it ended between `since` and `at`
    "manager",  # its service manager started it again by itself (at boot, or after it gave up)
    "clock",  # a clock edge
]


class Stamp(BaseModel):
    """When: which boot, how long after it began (never set), and the wall clock then."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    boot: str = Field(description="the kernel's boot id (/proc/sys/kernel/random/boot_id)")
    mono: float = Field(description="seconds since that boot (CLOCK_BOOTTIME)")
    wall: datetime = Field(description="the wall clock (UTC) as the car had it then")

    @property
    def offset(self) -> float:
        """wall - boottime: constant within a boot until the clock is set (a wall clock
        without a zone is UTC, as lpam writes it)."""
        wall = self.wall if self.wall.tzinfo is not None else \
            self.wall.replace(tzinfo=timezone.utc)
        return wall.timestamp() - self.mono


class Software(BaseModel):
    """Everything that decides what an app generation did, stored once by its digest."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    app: str
    generation: str
    repository: str = Field(description="key of the repository the app came from")
    commit: str
    path: str = Field(description="folder of the app inside its repository")
    tree: str = Field(description="git tree hash of the app folder")
    url: str | None = Field(default=None, description="the repository's URL as desired")
    commits: dict[str, str] = Field(
        default_factory=dict, description="every repository it runs from, key → commit "
        "(the app's own and its ROS sources')")
    params: dict[str, str] = Field(default_factory=dict)
    params_digest: str
    command: list[str] | None = None
    launch: str | None = None
    pip: list[str] = Field(default_factory=list, description="its pip environment as "
                           "installed (name==version), or its requirements when not known")
    apt: dict[str, str] = Field(default_factory=dict,
                                description="apt packages it needs → version installed")
    ros: dict[str, str] = Field(default_factory=dict,
                                description="its ROS repositories' commits, by name")
    lpam: str = Field(description="the version of lpam that ran it")
    desired_source: str | None = Field(
        default=None, description="the desired state's file, or `<repository>@<revision>"
        "/<file>`")
    desired_fingerprint: str | None = None
    vehicle: str | None = Field(default=None, description="the car's VIN or vehicle id")
    data: list[str] = Field(default_factory=list, description="where it writes data files")

    @property
    def digest(self) -> str:
        return software_digest(self)


class Edge(BaseModel):
    """One line of the timeline."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[1] = TIMELINE_VERSION
    kind: EdgeKind
    how: How
    at: Stamp
    app: str | None = None
    generation: str | None = None
    software: str | None = Field(default=None, description="digest of its Software")
    since: Stamp | None = Field(
        default=None, description="power-lost: the last moment it was known running "
        "(the end lies between `since` and `at`)")
    note: str | None = None


def params_digest(params: dict[str, str]) -> str:
    """A short, stable name of a set of parameters (what an app stamps its files with)."""
    text = json.dumps(params, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def software_digest(software: Software) -> str:
    text = json.dumps(software.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:20]


class Running(BaseModel):
    """An interval lpam saw begin and not yet end: what the next look at the service
    manager (and the next boot) compares with, so a crash, an exit or a power cut closes
    it with the last moment it was known running (`alive`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    app: str
    generation: str
    software: str | None = None
    unit: str | None = Field(default=None, description="the unit whose state says it runs")
    pid: int | None = Field(default=None, description="None: not looked at yet")
    restarts: int | None = Field(default=None, description="None: not looked at yet")
    began: Stamp
    alive: Stamp = Field(description="the last moment it was known running")


class RunningFile(BaseModel):
    """`var/lib/lpam/timeline/running.json`, rewritten atomically at every edge and look."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[1] = TIMELINE_VERSION
    running: list[Running] = Field(default_factory=list)


Certainty = Literal["recorded", "corrected", "uncertain"]


class When(BaseModel):
    """A moment as a sidecar says it: the best estimate, its bounds, how sure."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    when: datetime
    earliest: datetime
    latest: datetime
    certainty: Certainty = Field(description="recorded: the car's clock, not known wrong; "
                                 "corrected: mapped onto a later setting of the clock in "
                                 "the same boot; uncertain: only the window is known")


class Ran(BaseModel):
    """One generation that ran during the file's span."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    app: str
    generation: str
    software: Software | None = Field(description="None: it began before lpam kept a "
                                      "timeline, what ran is not recorded")
    began: When
    began_how: str
    ended: When | None = Field(description="None: still running when the file was stamped")
    ended_how: str | None = None
    restarts: list[When] = Field(default_factory=list)


class FileSpan(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    first: datetime | None
    last: datetime | None
    source: Literal["csv", "candump", "rosbag", "file-times"]
    vehicle: str | None = None


SIDECAR_VERSION: Literal[1] = 1


class Sidecar(BaseModel):
    """`<file>.provenance.json`, written next to each finished data file, so that what
    made it travels with it when it is uploaded (to CyVerse, by VIN)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[1] = SIDECAR_VERSION
    file: str = Field(description="the data file's name, beside this one")
    size: int = Field(description="its size when stamped: a file that grew since is "
                      "stamped again")
    span: FileSpan
    verdict: str = Field(description="ran | nothing ran | before lpam | other vehicle | "
                         "no times | clock uncertain")
    said: str | None = None
    ran: list[Ran] = Field(default_factory=list)
    or_ran: list[Ran] = Field(default_factory=list, description="clock uncertain: what "
                              "ran if the file's times were written before the clock was set")
    vehicle: str | None = Field(default=None, description="the car that stamped it")
    lpam: str
