"""One app generation as the plan's steps name it: `AppGeneration`.

A generation is an app folder's content at a commit and how it runs (scripts, or the
unit lpam writes for `command`/`launch`), with what it depends on (its pip environment,
its ROS build). The planner writes it into every app step once, typed, so the executor
never parses it back from strings, and a saved plan that lacks a field is refused when
it is loaded rather than when the step runs mid-cutover.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class AppGeneration(BaseModel):
    """The app a step works on. `commit`, `path` and `tree` are None only in a plan made
    without network (never applied: planning/plan.py refuses it)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    generation: str = Field(description="directory name under generations/<app>/")
    repository: str = Field(description="key of the repository the app comes from")
    commit: str | None
    path: str | None = Field(description="folder of the app inside its repository")
    tree: str | None = Field(description="git tree hash of the app folder")
    params: dict[str, str] = Field(default_factory=dict)
    service: str | None = None
    command: list[str] | None = Field(
        default=None, description="scriptless app: the program lpam runs as its unit")
    launch: str | None = Field(
        default=None, description="scriptless app: the roslaunch file lpam runs as its unit")
    user: str | None = Field(default=None, description="user a scriptless app runs as")
    pip: list[str] = Field(default_factory=list, description="its pip requirements")
    ros: dict[str, str] = Field(default_factory=dict,
                                description="its ROS repositories' commits, by name")
    ros_build: str | None = Field(default=None, description="the key of its ROS build")
    ros_workspace: str | None = None
    ros_user: str | None = None

    @property
    def scriptless(self) -> bool:
        return self.command is not None or self.launch is not None


class StrayGeneration(BaseModel):
    """An app found installed that the record does not own (schemas/record.py `Stray`):
    stopped and uninstalled by its own scripts, with the parameters it was found with."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    generation: str
    params: dict[str, str] = Field(default_factory=dict)
