"""A twin of the catkin workspace for fast tests of the planner and the steps.

It is `CatkinWorkspace` with the compiler taken out: the same spaces, links, folders moved
aside and collection, on disk under the test's temporary root (steps export sources into
`prepare`'s folder, and link targets must exist), but a build runs no catkin_make. It
succeeds at once, leaving a stub `devel/setup.bash`, unless `fail` maps its key to a
package, in which case it raises the very error a real failed build raises, after leaving
a half-built space as a real one would. It runs as whoever runs the tests, so it never
changes owners. `calls` records each operation, in order.
"""

from __future__ import annotations

import shlex
from collections.abc import Sequence
from pathlib import Path

from reconciler.adapters.catkin import CatkinWorkspace, build_failed, current_user
from reconciler.engine.execution.ports import Log


class MemoryWorkspace(CatkinWorkspace):
    """The `Workspace` port without catkin; `fail` maps a build key to the package that
    breaks its build."""

    def __init__(self, root: Path, *, fail: dict[str, str] | None = None) -> None:
        super().__init__(root, current_user(), underlay=None)
        self.fail: dict[str, str] = {} if fail is None else fail
        self.calls: list[tuple[str, ...]] = []

    def prepare(self, key: str) -> Path:
        self.calls.append(("prepare", key))
        return super().prepare(key)

    def build(self, key: str, *, log: Log) -> None:
        self.calls.append(("build", key))
        super().build(key, log=log)

    def link(self, key: str, repos: Sequence[str]) -> None:
        self.calls.append(("link", key, *repos))
        super().link(key, repos)

    def collect(self, keep: set[str]) -> None:
        self.calls.append(("collect", *sorted(keep)))
        super().collect(keep)

    def _compile(self, space: Path, log: Log) -> None:
        log(f"(memory workspace) building {space.name}")
        (space / "build").mkdir(exist_ok=True)
        package = self.fail.get(space.name)
        if package is not None:
            raise build_failed(package, [f"{package}: error: the build of {package} fails "
                                         "(memory workspace)"])
        devel = space / "devel"
        devel.mkdir(exist_ok=True)
        src = shlex.quote(str(space / "src"))
        (devel / "setup.bash").write_text(f"export ROS_PACKAGE_PATH={src}\n")
