"""One contract for the ROS workspace: the real CatkinWorkspace (Debian's catkin_make on tiny
packages under the test's temporary root) and the MemoryWorkspace the planner's fast tests
use.

What the steps rely on is written once for both: a build is prepared empty, is `built` only
after it succeeded and is then left alone; a failed build names the package, leaves no
marker, and the next `prepare` starts it clean; the workspace's `src/<repo>` links move from
build to build without a temporary name left over, and a real folder found there is moved
aside, never deleted; collection spares what is kept and what a link points into.

Real builds cost about two seconds each, so the real workspace builds only where a test
needs a finished (or failed) build; links and collection work on prepared spaces.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from reconciler.adapters.catkin import CatkinWorkspace, current_user
from reconciler.adapters.workspace_memory import MemoryWorkspace
from reconciler.base.errors import DependencyError
from reconciler.engine.execution.ports import Workspace
from tests.catkin import write_package

KEY = "0123abcd"
OTHER = "4567ef01"
OLD = "89abcdef" * 2
HALF = "fedcba98"


@dataclass
class World:
    """A workspace, and how to make a build of it fail where a real compiler would."""

    ws: Workspace
    breaks: Callable[[str, str], None]  # the build `key` fails in `package`
    mends: Callable[[str], None]  # … and no longer does


def _real(root: Path) -> World:
    if shutil.which("catkin_make") is None:
        pytest.skip("catkin_make is not on PATH (apt-get install catkin): the real workspace "
                    "cannot build")
    # The real compiler fails on the broken package's source by itself.
    return World(CatkinWorkspace(root, current_user()), lambda _k, _p: None, lambda _k: None)


def _memory(root: Path) -> World:
    twin = MemoryWorkspace(root)

    def mends(key: str) -> None:
        twin.fail.pop(key, None)

    return World(twin, twin.fail.__setitem__, mends)


@pytest.fixture(params=[_real, _memory], ids=["catkin", "memory"])
def world(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[World]:
    factory: Callable[[Path], World] = request.param
    yield factory(tmp_path / "home" / "circles" / "catkin_ws")


def test_a_build_is_prepared_empty_built_once_and_then_left_alone(world: World) -> None:
    ws = world.ws
    assert ws.space(KEY) == ws.root / ".lpam" / "builds" / KEY
    src = ws.prepare(KEY)
    assert src == ws.space(KEY) / "src" and src.is_dir() and list(src.iterdir()) == []
    assert not ws.built(KEY)
    write_package(src / "robot" / "alpha", "alpha")
    lines: list[str] = []
    ws.build(KEY, log=lines.append)
    assert ws.built(KEY) and not ws.built(OTHER)
    assert lines, "the build's output is streamed to the log"
    assert ws.setup_script(KEY) == ws.space(KEY) / "devel" / "setup.bash"
    assert ws.setup_script(KEY).is_file()

    marker = [p for p in ws.space(KEY).iterdir() if p.name.startswith(".lpam")]
    stamp = [p.stat().st_mtime_ns for p in marker]
    assert ws.prepare(KEY) == src, "preparing a finished build must not wipe it"
    ws.build(KEY, log=lines.append)
    assert ws.built(KEY) and (src / "robot" / "alpha" / "package.xml").is_file()
    assert [p.stat().st_mtime_ns for p in marker] == stamp, "a finished build is not rebuilt"


@pytest.mark.parametrize("key", ["", "abc", "ABCDEF12", "../../etc", "g" * 8, "a" * 65,
                                 "0123abcd/", " 0123abcd"])
def test_build_keys_are_hex_digests_and_nothing_else(world: World, key: str) -> None:
    for use in (world.ws.space, world.ws.prepare, world.ws.built):
        with pytest.raises(ValueError):
            use(key)
    assert not (world.ws.root / ".lpam" / "builds").exists()


def test_a_failed_build_names_the_package_leaves_no_marker_and_is_prepared_anew(
    world: World,
) -> None:
    ws = world.ws
    src = ws.prepare(KEY)
    write_package(src / "robot" / "good", "good")
    # The folder is not named like the package: the error names what catkin calls it.
    write_package(src / "robot" / "bad_folder", "bad_pkg", broken=True)
    world.breaks(KEY, "bad_pkg")
    lines: list[str] = []
    with pytest.raises(DependencyError) as caught:
        ws.build(KEY, log=lines.append)
    assert caught.value.message == "ROS workspace build failed in package bad_pkg"
    assert caught.value.details, "the error shows the compiler's output"
    assert caught.value.hint is not None and "untouched" in caught.value.hint
    assert not ws.built(KEY)
    assert [p.name for p in ws.space(KEY).iterdir() if p.name.startswith(".lpam")] == []
    assert (ws.space(KEY) / "build").is_dir(), "what the failed build left is still there"

    src = ws.prepare(KEY)
    assert list(src.iterdir()) == [] and sorted(os.listdir(ws.space(KEY))) == ["src"]
    world.mends(KEY)
    write_package(src / "robot" / "good", "good")
    ws.build(KEY, log=lines.append)
    assert ws.built(KEY)


def _sources(ws: Workspace, key: str, repo: str = "robot") -> None:
    write_package(ws.prepare(key) / repo / "alpha", "alpha")


def test_link_points_src_at_a_build_and_replaces_the_older_link(world: World) -> None:
    ws = world.ws
    _sources(ws, KEY)
    _sources(ws, OTHER)
    link = ws.root / "src" / "robot"
    ws.link(KEY, ["robot"])
    assert link.is_symlink() and os.readlink(link) == f"../.lpam/builds/{KEY}/src/robot"
    assert (link / "alpha" / "package.xml").is_file()
    ws.link(OTHER, ["robot"])
    assert os.readlink(link) == f"../.lpam/builds/{OTHER}/src/robot"
    assert os.listdir(ws.root / "src") == ["robot"], "no temporary link is left behind"
    assert not (ws.root / ".lpam" / "replaced").exists(), "a link is replaced, not kept"


def test_a_real_folder_where_a_link_goes_is_moved_aside_never_deleted(world: World) -> None:
    ws = world.ws
    clone = ws.root / "src" / "robot"
    clone.mkdir(parents=True)
    (clone / "notes.txt").write_text("mine")
    _sources(ws, KEY)
    ws.link(KEY, ["robot"])
    assert clone.is_symlink()
    replaced = ws.root / ".lpam" / "replaced"
    assert (replaced / "robot" / "notes.txt").read_text() == "mine"

    clone.unlink()  # someone clones it by hand again
    clone.mkdir()
    (clone / "notes.txt").write_text("mine too")
    ws.link(KEY, ["robot"])
    assert clone.is_symlink()
    assert (replaced / "robot" / "notes.txt").read_text() == "mine"
    assert (replaced / "robot.1" / "notes.txt").read_text() == "mine too"


@pytest.mark.parametrize("repo", ["", ".", "..", "../escape", "a/b", ".hidden", "missing"])
def test_link_refuses_names_that_leave_src_and_sources_the_build_lacks(
    world: World, repo: str,
) -> None:
    ws = world.ws
    _sources(ws, KEY)
    with pytest.raises(ValueError):
        ws.link(KEY, ["robot", repo])
    assert not (ws.root / "src" / "robot").exists(), "nothing is linked when one name is bad"


def test_collect_removes_what_is_neither_kept_nor_linked(world: World) -> None:
    ws = world.ws
    _sources(ws, KEY)
    _sources(ws, OTHER)
    ws.prepare(HALF)
    ws.prepare(OLD)
    ws.build(OLD, log=lambda _line: None)  # an empty workspace builds too
    ws.link(OTHER, ["robot"])
    ws.collect({KEY})
    assert sorted(os.listdir(ws.root / ".lpam" / "builds")) == sorted([KEY, OTHER])
    assert (ws.root / "src" / "robot" / "alpha" / "package.xml").is_file()

    ws.link(KEY, ["robot"])
    ws.collect(set())
    assert os.listdir(ws.root / ".lpam" / "builds") == [KEY], "the linked build stays"
    ws.collect(set())  # idempotent
    assert os.listdir(ws.root / ".lpam" / "builds") == [KEY]
