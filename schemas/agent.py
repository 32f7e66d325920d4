"""The agent's configuration (`<root>/etc/lpam/agent.yaml`) and what it records of its
passes (`<root>/var/lib/lpam/status.json`, also the body of the branch `status/<vehicle>`
it publishes, see reconciler/core/publication.py).

```yaml
version: 1
source: {url: "https://github.com/our-lab/fleet-state", branch: main}
vehicle_file: /etc/libpanda.d/vin      # or `vehicle: rav4-07`; default: the hostname
interval_seconds: 300
heartbeat_seconds: 21600               # publish an unchanged status this often (6 h)
trust: {allowed_signers: /etc/lpam/allowed_signers}   # optional: signed commits only
```

In the source repository, `vehicles/<id>.yaml` is this vehicle's desired state when it
exists, else `desired-state.yaml` at its root.

The agent status is a document lpam writes, so it changes only through a version and a
migration (migrations/agent_status_v1_to_v2.py): version 2 names the result `deferred`,
the file the vehicle follows (`follows`) and its last publication (`publication`).
`rollout` (issue 34), where the car stands in the rollout its desired state declares, is
optional and written only when there is one: a car with no rollout writes the file it
wrote before, which an lpam from before rollouts still reads.
"""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    StrictStr,
    ValidationInfo,
    field_validator,
    model_serializer,
)

from schemas.names import check_ref, check_url
from schemas.rollout import RolloutState

CURRENT_VERSION = 1
_VEHICLE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,62}$")
PASSES_KEPT = 10


def check_vehicle(value: str) -> str:
    """A vehicle id names a file (`vehicles/<id>.yaml`) and a branch (`status/<id>`)."""
    if not _VEHICLE.match(value) or ".." in value or value.endswith((".", ".lock")):
        raise ValueError(f"vehicle id {value!r}: use letters, digits, '_', '-', '.' (at most "
                         "63 characters, e.g. rav4-07 or a VIN)")
    return value


class Source(BaseModel):
    """The desired-state repository the vehicle follows."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    url: StrictStr = Field(description="https://, git://, ssh://, file:// URL or a path")
    branch: StrictStr = Field(default="main", description="the branch the vehicle follows")

    @field_validator("url")
    @classmethod
    def _url(cls, value: str) -> str:
        return check_url(value)

    @field_validator("branch")
    @classmethod
    def _branch(cls, value: str) -> str:
        return check_ref(value)


class Trust(BaseModel):
    """Only commits signed by a listed SSH key are applied."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    allowed_signers: StrictStr = Field(
        description="OpenSSH allowed_signers file (absolute path, under --root)")

    @field_validator("allowed_signers")
    @classmethod
    def _path(cls, value: str) -> str:
        if not value.startswith("/") or ".." in value.split("/"):
            raise ValueError("allowed_signers must be an absolute path without '..'")
        return value


class AgentConfig(BaseModel):
    """How this vehicle follows its desired state."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[1] = Field(description="document version; this is version 1")
    source: Source
    vehicle: StrictStr | None = Field(default=None, description="this vehicle's id")
    vehicle_file: StrictStr | None = Field(
        default=None, description="a file holding the id (e.g. /etc/libpanda.d/vin)")
    interval_seconds: float = Field(default=300, ge=10, le=86400,
                                    description="seconds between passes of `lpam agent`")
    heartbeat_seconds: float = Field(
        default=6 * 3600, ge=300, le=7 * 86400,
        description="publish this vehicle's status at least this often even when it did not "
        "change, so that the fleet sees the car is alive (between 5 minutes and 7 days; "
        "at least interval_seconds)")
    trust: Trust | None = Field(default=None, description="apply only signed commits")
    gate_wait_seconds: float = Field(
        default=0, ge=0, le=3600, description="how long a pass may wait for closed update "
        "gates before deferring to the next pass (a live bus has no history: give more "
        "than gates.stationary_seconds)")

    @field_validator("vehicle")
    @classmethod
    def _vehicle(cls, value: str | None) -> str | None:
        return None if value is None else check_vehicle(value)

    @field_validator("vehicle_file")
    @classmethod
    def _vehicle_file(cls, value: str | None, info: ValidationInfo) -> str | None:
        if value is not None and (not value.startswith("/") or ".." in value.split("/")):
            raise ValueError("vehicle_file must be an absolute path without '..'")
        if value is not None and info.data.get("vehicle") is not None:
            raise ValueError("give `vehicle:` or `vehicle_file:`, not both")
        return value

    @field_validator("heartbeat_seconds")
    @classmethod
    def _heartbeat(cls, value: float, info: ValidationInfo) -> float:
        interval = info.data.get("interval_seconds")
        if interval is not None and value < interval:
            raise ValueError(f"{value:g} is shorter than interval_seconds "
                             f"({interval:g}): every pass would publish; give at least the "
                             "interval (the default is 21600, 6 hours)")
        return value


Result = Literal["applied", "nothing to do", "offline", "failed", "rolled back", "fetched",
                 "stopped", "deferred"]


class Attempt(BaseModel):
    """One pass: when, which revision of the source, how it ended and why."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    time: str
    revision: str | None
    result: Result
    reason: str | None = None


Published = Literal["pushed", "refused", "failed"]


class Publication(BaseModel):
    """The last attempt to publish this status to `status/<vehicle>`: when, the fingerprint
    of what counted in it (reconciler/core/publication.py), and whether the fleet repository
    took it (`pushed`), refused pushes from this car (`refused`: read-only, no write
    access), or could not be reached (`failed`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    time: str
    fingerprint: str
    result: Published
    reason: str | None = None


class AgentStatus(BaseModel):
    """What the agent knows of its source: the revision it would apply, the last one it
    applied, the file of the source it follows, the last attempt (a failed revision is not
    tried again until a new one arrives), the last passes, and its last publication."""

    model_config = ConfigDict(extra="forbid")

    version: Literal[2] = 2
    vehicle: str | None = None
    follows: str | None = Field(
        default=None, description="the desired-state file of the source this vehicle "
        "follows at desired_revision: vehicles/<id>.yaml or desired-state.yaml")
    desired_revision: str | None = None
    applied_revision: str | None = None
    last_attempt: Attempt | None = None
    passes: list[Attempt] = Field(default_factory=list)
    publication: Publication | None = None
    rollout: RolloutState | None = Field(
        default=None, description="where this car stands in the rollout of the revision it "
        "follows (None: its desired state declares no rollout)")

    @model_serializer(mode="wrap")
    def _without_rollout(self, handler: SerializerFunctionWrapHandler) -> Any:
        """No `rollout: null`: a car with no rollout writes what it wrote before."""
        body = handler(self)
        if isinstance(body, dict) and body.get("rollout", 0) is None:
            del body["rollout"]
        return body

    def failed(self, revision: str) -> bool:
        """Whether `revision` was tried and failed (so it is not tried again)."""
        last = self.last_attempt
        return last is not None and last.revision == revision and \
            last.result in ("failed", "rolled back")
