"""One app generation, in the shapes lpam keeps it: a plan's step (`AppGeneration`), the
state record's installed app (schemas/record.py `AppRecord`) and the metadata file beside
the generation on disk (`GenerationMeta`), all on the same fields (`GenerationFields`).

A generation is an app folder's content at a commit and how it runs (scripts, or the
unit lpam writes for `command`/`launch`), with what it depends on (its pip environment,
its ROS build). The planner writes it into every app step once, typed, so the executor
never parses it back from strings, and a saved plan that lacks a field is refused when
it is loaded rather than when the step runs mid-cutover.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, model_serializer

UNKNOWN_CLAIMS = frozenset({"panda"})
"""What an app whose claims are not known holds: before lpam knew claims, every app it
installed ran alone and owned the panda (schemas/catalog.py PANDA)."""


class GenerationFields(BaseModel):
    """What every shape of an app generation says: which app, which generation, where it
    came from, its parameters and how it runs. A plan's step (AppGeneration), the state
    record's installed app (schemas/record.py AppRecord) and the metadata file beside the
    generation (GenerationMeta) each extend it with what only they know."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    generation: str = Field(description="directory name under generations/<app>/")
    repository: str = Field(description="key of the repository the app came from")
    params: dict[str, str] = Field(default_factory=dict)
    service: str | None = Field(
        default=None, description="the unit whose state says whether the app runs: the "
        "one lpam wrote (scriptless app) or the one named in the app's `service` file")
    command: list[str] | None = Field(
        default=None, description="scriptless app: the program lpam runs as its unit")
    launch: str | None = Field(
        default=None, description="scriptless app: the roslaunch file lpam runs as its unit")
    user: str | None = Field(default=None, description="user a scriptless app runs as")
    resources: list[str] | None = Field(
        default=None, description="the exclusive resources it claims (`panda`, "
        "`service:can`, …): no other installed app may claim one of them. None: not "
        "known (installed before lpam knew claims), taken as `panda`, which every app "
        "owned then")

    data: list[str] = Field(
        default_factory=list, description="where it writes data files (absolute paths or "
        "globs, under lpam's root): lpam stamps each finished one with what ran")

    @property
    def scriptless(self) -> bool:
        return self.command is not None or self.launch is not None

    @model_serializer(mode="wrap")
    def _claims_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        """`resources` is written only when known, and `data` only when given: a plan's
        seal, a state record and a generation's metadata written before apps named them
        stay what they were (a saved plan's seal still matches)."""
        data = handler(self)
        if isinstance(data, dict) and data.get("resources", ()) is None:
            del data["resources"]
        if isinstance(data, dict) and data.get("data", None) == []:
            del data["data"]  # as for resources: what older lpams wrote stays as it was
        return data

    @property
    def claims(self) -> frozenset[str]:
        """The resources it holds while installed (`panda` when not known)."""
        return frozenset(self.resources) if self.resources is not None else UNKNOWN_CLAIMS


class AppGeneration(GenerationFields):
    """The app a step works on, with what it depends on. `commit`, `path` and `tree` are
    None only in a plan made without network (never applied: core/planning/plan.py refuses
    it)."""

    commit: str | None
    path: str | None = Field(description="folder of the app inside its repository")
    tree: str | None = Field(description="git tree hash of the app folder")
    pip: list[str] = Field(default_factory=list, description="its pip requirements")
    ros: dict[str, str] = Field(default_factory=dict,
                                description="its ROS repositories' commits, by name")
    ros_build: str | None = Field(default=None, description="the key of its ROS build")
    ros_workspace: str | None = None
    ros_user: str | None = None


GENERATION_META_VERSION: Literal[1] = 1


class GenerationMeta(GenerationFields):
    """The metadata file beside a generation (`generations/<app>/<id>.json`), written when
    it is staged: what lets lpam stop and uninstall the app with its own scripts even
    without a state record, tells a script deleted by the app apart from one it never
    had (`scripts`; None: staged by an lpam that did not record them), and keeps the
    runtime it was staged with (its environment, its ROS build) for a rollback. Version
    1 is the first with a version (engine/records/generations.py reads older files through
    migrations/generation_meta_v0_to_v1.py). Unknown keys are ignored, as they always
    were: the file is a cache of what the stage step knew. The engine holds a generation
    as this very model (reconciler/core/planning/model.py `Generation` adds its folder only),
    so what it stages is what this file says."""

    model_config = ConfigDict(extra="ignore", frozen=True)

    version: Literal[1] = GENERATION_META_VERSION
    repository: str = ""
    commit: str = ""
    path: str = ""
    tree: str = ""
    scripts: list[str] | None = None
    venv: str | None = Field(default=None,
                             description="the virtual environment of its pip requirements")
    ros: dict[str, str] = Field(default_factory=dict)
    ros_build: str | None = None
    ros_workspace: str | None = None
    ros_user: str | None = None


class StrayGeneration(BaseModel):
    """An app found installed that the record does not own (schemas/record.py `Stray`):
    stopped and uninstalled by its own scripts, with the parameters it was found with."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    generation: str
    params: dict[str, str] = Field(default_factory=dict)
