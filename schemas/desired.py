"""Desired state, version 2: the document an operator writes (or commits for the Pi to watch).

```yaml
version: 2
repositories:
  - repo: jmscslgroup/libpanda-default-apps   # or url: https://… | git://… | file://… | path
    ref: main                                  # branch, tag, full or abbreviated commit
apps:                                          # a list; `apps: []` for none
  - name: pandarecord                          # or the name alone: `- pandarecord`
    repository: jmscslgroup/libpanda-default-apps  # only when two repositories offer it
    params: {RATE_HZ: "10"}
mirrors: {"https://github.com/": "git://192.168.4.1/"}   # optional: git's insteadOf
ros: {workspace: /home/circles/catkin_ws, user: circles}  # optional: these are defaults
vehicle: {source: {follow: /etc/libpanda.d/currentCan.csv}}  # optional: schemas/vehicle.py
gates: {stationary_seconds: 60, windows: ["22:00-06:00"]}  # optional: no gates without it
```

Version 1 said `app: X` (one app, or `app: null`); it is still read, through
migrations/desired_state_v1_to_v2.py, and lpam's own edits keep such a file version 1.
Version 2 lists apps, which run side by side (core/planning/ensemble.py); two that claim one
exclusive resource are refused when planned (core/planning/resources.py). One app is a
list of one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    StrictStr,
    field_validator,
    model_serializer,
    model_validator,
)

from schemas.names import (
    URL_SCHEMES,
    check_app_name,
    check_data,
    check_owner_repo,
    check_param_name,
    check_ref,
    check_url,
    repository_key,
)
from schemas.rollout import RolloutSpec
from schemas.service import Health, check_user
from schemas.vehicle import GatesSpec, VehicleSpec

CURRENT_VERSION = 2
PARAM_VALUE_LIMIT = 4096  # an environment variable's value; kernels cap one at 128 KiB


class RepositorySpec(BaseModel):
    """One app repository, optionally pinned to a ref."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    repo: StrictStr | None = Field(
        default=None, description="GitHub shorthand 'owner/name' (https://github.com/owner/name)"
    )
    url: StrictStr | None = Field(
        default=None,
        description="https://, git://, ssh://, file:// URL or a path (relative to this file)",
    )
    ref: StrictStr | None = Field(
        default=None,
        description="branch, tag, full or abbreviated commit; absent: the remote's default branch",
    )
    name: StrictStr | None = Field(
        default=None,
        description="short name in plans and for app.repository; default: from repo or url",
    )

    @field_validator("name")
    @classmethod
    def _name(cls, value: str | None) -> str | None:
        if value is None:
            return None
        return check_owner_repo(value) if "/" in value else check_app_name(value)

    @field_validator("repo")
    @classmethod
    def _repo(cls, value: str | None) -> str | None:
        return None if value is None else check_owner_repo(value)

    @field_validator("url")
    @classmethod
    def _url(cls, value: str | None) -> str | None:
        return None if value is None else check_url(value)

    @field_validator("ref")
    @classmethod
    def _ref(cls, value: str | None) -> str | None:
        return None if value is None else check_ref(value)

    @model_validator(mode="after")
    def _one_source(self) -> RepositorySpec:
        if (self.repo is None) == (self.url is None):
            raise ValueError("give exactly one of 'repo: owner/name' or 'url: …'")
        return self

    @property
    def key(self) -> str:
        """The repository's name in plans, the store and `app.repository`."""
        if self.name is not None:
            return self.name
        if self.repo is not None:
            return self.repo
        assert self.url is not None
        return repository_key(self.url)

    def source(self, base_dir: Path) -> str:
        """The URL git is given: shorthand expanded, relative paths made absolute."""
        if self.repo is not None:
            return f"https://github.com/{self.repo}"
        assert self.url is not None
        if "://" in self.url:
            return self.url
        path = Path(self.url).expanduser()
        return str(path if path.is_absolute() else (base_dir / path).resolve())


class AppSpec(BaseModel):
    """An app the vehicle should have installed and running."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: StrictStr
    repository: StrictStr | None = Field(
        default=None, description="key or URL of the repository; needed only when ambiguous"
    )
    params: dict[StrictStr, StrictStr] = Field(
        default_factory=dict, description="environment variables given to the app's scripts"
    )
    user: StrictStr | None = Field(
        default=None, description="user a scriptless app runs as (default: the libpanda "
        "user named in /etc/libpanda.d/libpanda_usr, else root)")
    health: Health | None = Field(
        default=None, description="overrides the catalog's health check, field by field")
    data: list[StrictStr] | None = Field(
        default=None, description="where the app writes data files (absolute paths or "
        "globs), for an app whose catalog cannot say it; None: the catalog's")

    @field_validator("data")
    @classmethod
    def _data(cls, value: list[str] | None) -> list[str] | None:
        return None if value is None else check_data(value)

    @model_serializer(mode="wrap")
    def _data_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        """`data` only when given: a desired state's fingerprint, which holds are held
        against, stays what an lpam before `data:` recorded (core/planning/holds.py)."""
        dumped = handler(self)
        if isinstance(dumped, dict) and dumped.get("data", ()) is None:
            del dumped["data"]
        return dumped

    @field_validator("name")
    @classmethod
    def _name(cls, value: str) -> str:
        return check_app_name(value)

    @field_validator("user")
    @classmethod
    def _user(cls, value: str | None) -> str | None:
        return None if value is None else check_user(value)

    @field_validator("params")
    @classmethod
    def _params(cls, value: dict[str, str]) -> dict[str, str]:
        for key, item in value.items():
            check_param_name(key)
            if "\x00" in item:
                raise ValueError(f"parameter {key!r} contains a NUL byte")
            if len(item) > PARAM_VALUE_LIMIT:
                raise ValueError(f"parameter {key!r} is longer than {PARAM_VALUE_LIMIT} "
                                 "characters")
        return value


def duplicate_app(name: str, first: int) -> str:
    """Why a second entry of one app name is refused (documents.py places it)."""
    return (f"app {name} is listed twice (first as item {first + 1} of apps); list each app "
            "once")


class RosSpec(BaseModel):
    """The ROS catkin workspace apps' `ros_repositories` are built in."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    workspace: StrictStr | None = Field(
        default=None, description="absolute path of the catkin workspace (under --root); "
        "default: the ROS user's ~/catkin_ws, where the field's scripts look")
    user: StrictStr | None = Field(
        default=None, description="user catkin_make runs as; default: the libpanda user "
        "named in /etc/libpanda.d/libpanda_usr, else root")

    @field_validator("workspace")
    @classmethod
    def _workspace(cls, value: str | None) -> str | None:
        if value is None:
            return None
        parts = value.split("/")
        if not value.startswith("/") or ".." in parts or len(value) > 255 or "\x00" in value:
            raise ValueError("ros.workspace must be an absolute path without '..' "
                             "(e.g. /home/circles/catkin_ws)")
        return value

    @field_validator("user")
    @classmethod
    def _user(cls, value: str | None) -> str | None:
        return None if value is None else check_user(value)


class DesiredState(BaseModel):
    """What the operator wants the vehicle to have."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[2] = Field(description="document version; this is version 2")
    repositories: list[RepositorySpec] = Field(default_factory=list)
    apps: list[AppSpec] = Field(default_factory=list, description="the apps to install and "
                                "run, each name once; an item may be the app's name alone")
    mirrors: dict[StrictStr, StrictStr] = Field(
        default_factory=dict, description="URL prefix → replacement, as git's "
        "url.<base>.insteadOf: app and ROS repositories are fetched from the replacement")
    ros: RosSpec = Field(default_factory=RosSpec)
    vehicle: VehicleSpec = Field(default_factory=VehicleSpec,
                                 description="how lpam reads the vehicle's speed")
    gates: GatesSpec | None = Field(default=None, description="when a cutover may happen; "
                                    "absent: at any moment")
    rollout: RolloutSpec | None = Field(
        default=None, description="for a fleet: which cars take a new revision first, and "
        "the proof the next wave waits for; absent: every car at once")

    @field_validator("mirrors")
    @classmethod
    def _mirrors(cls, value: dict[str, str]) -> dict[str, str]:
        for prefix, replacement in value.items():
            for text in (prefix, replacement):
                if "://" not in text or not text.startswith(URL_SCHEMES):
                    raise ValueError(f"mirror {text!r}: both sides must be URL prefixes "
                                     f"({', '.join(URL_SCHEMES)})")
                check_url(text.rstrip("/") or text)
        return value

    def mirrored(self, url: str) -> str:
        """`url` with the longest matching mirror prefix replaced (git's insteadOf rule)."""
        matches = [p for p in self.mirrors if url.startswith(p)]
        if not matches:
            return url
        prefix = max(matches, key=len)
        return self.mirrors[prefix] + url[len(prefix):]

    @field_validator("apps", mode="before")
    @classmethod
    def _app_shorthand(cls, value: Any) -> Any:
        if not isinstance(value, list):
            return value
        return [{"name": item} if isinstance(item, str) else item for item in value]

    @model_validator(mode="after")
    def _unique(self) -> DesiredState:
        names: dict[str, int] = {}
        for index, app in enumerate(self.apps):
            if app.name in names:
                raise ValueError(duplicate_app(app.name, names[app.name]))
            names[app.name] = index
        seen: dict[str, int] = {}
        for index, spec in enumerate(self.repositories):
            for name in {spec.key, spec.url or spec.repo or ""}:
                if name in seen:
                    raise ValueError(
                        f"repositories {seen[name] + 1} and {index + 1} are both called "
                        f"{name!r}: list each repository once, or give one a distinct `name:`"
                    )
                seen[name] = index
        return self

    def repository(self, name: str) -> RepositorySpec | None:
        """Find a repository by key, shorthand or URL."""
        for spec in self.repositories:
            if name in (spec.key, spec.repo, spec.url, spec.name):
                return spec
        return None
