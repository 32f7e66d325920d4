"""The state record: what lpam last did to this machine (`var/lib/lpam/state.json`).

Like Terraform's state it has a *lineage* (a UUID fixed when the record is first written)
and a *serial* (incremented on every write), so a saved plan can tell whether the machine
changed since it was made. It is rewritten atomically after every step that changes the
machine, so after a power cut it still says exactly which steps took effect.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

CURRENT_VERSION = 1


class RepositoryRecord(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    key: str
    url: str
    ref: str | None = Field(description="what the desired state asked for")
    commit: str = Field(description="full hash checked out in the store")


class AppRecord(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    repository: str = Field(description="key of the repository the app came from")
    commit: str = Field(description="commit the installed generation was copied from")
    tree: str = Field(description="git tree hash of the app folder at that commit")
    path: str = Field(description="folder of the app inside its repository")
    params: dict[str, str] = Field(default_factory=dict)
    generation: str = Field(description="directory name under generations/<app>/")
    running: bool = False


class StateRecord(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[1] = 1
    lineage: str | None = None
    serial: int = 0
    repositories: list[RepositoryRecord] = Field(default_factory=list)
    app: AppRecord | None = None

    def repository(self, key: str) -> RepositoryRecord | None:
        return next((r for r in self.repositories if r.key == key), None)
