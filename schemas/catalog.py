"""The app catalog: `libpanda-apps.yaml` at the root of an app repository.

Two shapes exist in the wild (lpam-legacy.md). The paper's nests everything under a
`properties:` map; the field's (libpanda-default-apps) has `path:`, `properties:` as a
list of one-key maps, and `dependencies:` / `ros_repositories:` at the app's own level.
`RawCatalog` accepts both strictly; `normalise` turns either into `Catalog`, the one
model the rest of lpam uses.
"""

from __future__ import annotations

import re
from typing import Annotated, Any

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictStr,
    WithJsonSchema,
    field_validator,
    model_validator,
)

from schemas.dependency import check_debian_package, check_requirement
from schemas.names import (
    check_app_name,
    check_data,
    check_owner_repo,
    check_ref,
    check_url,
)
from schemas.service import Health, check_argv, check_launch

CATALOG_FILE = "libpanda-apps.yaml"
APP_FILES = ("install.sh", "uninstall.sh", "start.sh", "stop.sh", "description.txt", "service")
PANDA = "panda"  # the resource the real catalogs' `owns_panda: true` claims
SERVICE_PREFIX = "service:"  # a claimed unit, `service:can`; ':' keeps it apart from names
_RESOURCE = re.compile(r"^[a-z0-9][a-z0-9-]{0,63}$")


def check_resource_name(value: str) -> str:
    """An exclusive resource's name (`panda`, `gps-serial`): lower-case letters, digits and
    '-', so that one resource is never spelt two ways (`Panda`, `panda `) and slips past
    the one-owner check."""
    if not _RESOURCE.match(value):
        raise ValueError(f"resource {value!r} is not a resource name: use lower-case letters, "
                         "digits and '-' (such as panda, gps-serial), at most 64")
    return value


ResourceName = Annotated[
    StrictStr, AfterValidator(check_resource_name),
    WithJsonSchema({"type": "string", "pattern": _RESOURCE.pattern}),  # editors check it too
]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RawRosRepository(_Strict):
    owner: StrictStr
    repo: StrictStr
    branch_or_hash: StrictStr | None = None
    url: StrictStr | None = None

    @field_validator("branch_or_hash")
    @classmethod
    def _ref(cls, value: str | None) -> str | None:
        return None if value is None else check_ref(value)

    @field_validator("url")
    @classmethod
    def _url(cls, value: str | None) -> str | None:
        if value is not None and "://" not in value:
            raise ValueError("a ROS repository's url must be a URL (https://, git://, …)")
        return None if value is None else check_url(value)


class RawDependency(_Strict):
    """One `{apt: NAME}` or `{pip3: REQUIREMENT}` entry."""

    apt: StrictStr | None = None
    pip3: StrictStr | None = None

    @field_validator("apt")
    @classmethod
    def _apt(cls, value: str | None) -> str | None:
        return None if value is None else check_debian_package(value)

    @field_validator("pip3")
    @classmethod
    def _pip3(cls, value: str | None) -> str | None:
        return None if value is None else check_requirement(value)

    @model_validator(mode="after")
    def _one(self) -> RawDependency:
        if (self.apt is None) == (self.pip3 is None):
            raise ValueError("give exactly one of `apt: PACKAGE` or `pip3: REQUIREMENT`")
        return self


class RawProperties(_Strict):
    """The paper's shape: a map under `properties:`."""

    owns_panda: StrictBool | None = None
    resources: list[ResourceName] = Field(default_factory=list)
    dependencies: list[RawDependency] = Field(default_factory=list)
    ros_repositories: list[RawRosRepository] = Field(default_factory=list)


class RawFlag(_Strict):
    """The field's shape: `properties:` is a list of one-key maps such as `- owns_panda: true`."""

    owns_panda: StrictBool | None = None


class RawApp(_Strict):
    name: StrictStr
    path: StrictStr | None = None
    description: StrictStr | None = None
    properties: RawProperties | list[RawFlag] | None = None
    resources: list[ResourceName] = Field(
        default_factory=list,
        description="exclusive resources the app claims (panda, gps-serial, …): no two "
        "desired apps may claim one")
    dependencies: list[RawDependency] = Field(default_factory=list)
    ros_repositories: list[RawRosRepository] = Field(default_factory=list)
    command: list[StrictStr] | None = None
    launch: StrictStr | None = None
    health: Health | None = None
    data: list[StrictStr] = Field(
        default_factory=list, description="where the app writes data files (absolute "
        "paths or globs): lpam stamps each finished one with the software that ran")

    @field_validator("data")
    @classmethod
    def _data(cls, value: list[str]) -> list[str]:
        return check_data(value)

    @field_validator("name")
    @classmethod
    def _name(cls, value: str) -> str:
        return check_app_name(value)

    @field_validator("command")
    @classmethod
    def _command(cls, value: list[str] | None) -> list[str] | None:
        return None if value is None else check_argv(value)

    @field_validator("launch")
    @classmethod
    def _launch(cls, value: str | None) -> str | None:
        return None if value is None else check_launch(value)

    @field_validator("path")
    @classmethod
    def _path(cls, value: str | None) -> str | None:
        if value is None:
            return None
        parts = [p for p in value.strip("/").split("/") if p not in ("", ".")]
        if value.startswith("/") or ".." in parts or not parts:
            raise ValueError("path must be a folder inside the repository (relative, no '..')")
        return "/".join(parts)


class RawCatalog(_Strict):
    apps: list[RawApp] = Field(default_factory=list)


class RosRepository(_Strict):
    owner: str
    repo: str
    ref: str | None = Field(default=None, description="branch or commit; None: default branch")
    url: str | None = Field(default=None, description="where to fetch it; default GitHub")

    @property
    def source(self) -> str:
        """The URL git is given, before the desired state's mirrors are applied."""
        return self.url or f"https://github.com/{self.owner}/{self.repo}"


class CatalogApp(_Strict):
    """One app as lpam understands it, whichever shape the catalog used."""

    name: str
    path: str
    description: str = ""
    service: str | None = None
    owns_panda: bool = False
    resources: frozenset[str] = Field(
        default=frozenset(), description="exclusive resources claimed in the catalog: "
        "`resources:`, and `panda` for `owns_panda: true` (the `service` unit is added "
        "where the app's folder is read)")
    apt: list[str] = Field(default_factory=list)
    pip3: list[str] = Field(default_factory=list)
    ros_repositories: list[RosRepository] = Field(default_factory=list)
    command: list[str] | None = Field(
        default=None, description="scriptless app: the program lpam runs as a service")
    launch: str | None = Field(
        default=None, description="scriptless app: PACKAGE/FILE.launch run with roslaunch")
    health: Health | None = None
    data: list[str] = Field(default_factory=list, description="where it writes data files")


class Catalog(_Strict):
    apps: list[CatalogApp] = Field(default_factory=list)

    def app(self, name: str) -> CatalogApp | None:
        return next((a for a in self.apps if a.name == name), None)


class CatalogFault(ValueError):
    """A fault `normalise` finds, with where it is (`loc`) in the catalog document."""

    def __init__(self, message: str, loc: tuple[str | int, ...]) -> None:
        super().__init__(message)
        self.loc = loc


def normalise(raw: RawCatalog) -> Catalog:
    """Both wild shapes to the one model; CatalogFault on a repeated app name or a bad ROS
    repository name."""
    apps: list[CatalogApp] = []
    seen: set[str] = set()
    for index, app in enumerate(raw.apps):
        if app.name in seen:
            raise CatalogFault(f"app {app.name!r} is listed twice", ("apps", index, "name"))
        if app.command is not None and app.launch is not None:
            raise CatalogFault(f"app {app.name}: give either `command:` or `launch:`, not "
                               "both", ("apps", index, "launch"))
        seen.add(app.name)
        deps = list(app.dependencies)
        ros = list(app.ros_repositories)
        owns = False
        claims = set(app.resources)
        if isinstance(app.properties, RawProperties):
            deps += app.properties.dependencies
            ros += app.properties.ros_repositories
            owns = bool(app.properties.owns_panda)
            claims.update(app.properties.resources)
        elif isinstance(app.properties, list):
            owns = any(bool(flag.owns_panda) for flag in app.properties)
        names: set[str] = set()
        for r in ros:
            try:
                check_owner_repo(f"{r.owner}/{r.repo}")
            except ValueError as exc:
                raise CatalogFault(f"app {app.name}: ROS repository: {exc}",
                                   ("apps", index)) from None
            if r.repo in names:  # both would be checked out as src/<repo>
                raise CatalogFault(f"app {app.name}: two ROS repositories are named "
                                   f"{r.repo!r}; each is checked out as src/{r.repo}",
                                   ("apps", index, "ros_repositories"))
            names.add(r.repo)
        apps.append(
            CatalogApp(
                name=app.name,
                path=app.path or app.name,
                description=app.description or "",
                owns_panda=owns,
                resources=frozenset(claims | ({PANDA} if owns else set())),
                apt=[d.apt for d in deps if d.apt],
                pip3=[d.pip3 for d in deps if d.pip3],
                ros_repositories=[
                    RosRepository(owner=r.owner, repo=r.repo, ref=r.branch_or_hash, url=r.url)
                    for r in ros
                ],
                command=app.command,
                launch=app.launch,
                health=app.health,
                data=list(app.data),
            )
        )
    return Catalog(apps=apps)


def with_folder_files(app: CatalogApp, files: dict[str, bytes]) -> CatalogApp:
    """Fill description and service from the app folder's `description.txt` / `service`."""
    update: dict[str, Any] = {}
    if "description.txt" in files and not app.description:
        lines = files["description.txt"].decode("utf-8", "replace").strip().splitlines()
        update["description"] = lines[0].strip() if lines else ""
    if "service" in files:
        service = files["service"].decode("utf-8", "replace").strip()
        update["service"] = service or None
    return app.model_copy(update=update) if update else app
