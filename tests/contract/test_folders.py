"""The AppFolders port (engine/execution/ports.py) held to what the engine relies on, against its
disk implementation (adapters/folders.py): staging is idempotent, a folder that went missing
is restored from the store (and a tree that is not the planned one refused), the installed
generation is reachable at `/etc/libpanda.d/apps/<folder>`, and releasing or pruning keeps
what another generation still needs."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import MemoryStore
from reconciler.base.errors import StepError
from reconciler.base.layout import Layout
from reconciler.core.planning.model import Generation, GenerationKey
from reconciler.engine.execution.ports import AppFolders

URL, KEY = "git://h/apps", "lab/apps"
OLD, NEW = "a" * 40, "b" * 40
TREE_OLD, TREE_NEW = "1" * 40, "2" * 40
GEN_OLD, GEN_NEW = "0123456789ab-01234567", "ba9876543210-76543210"


@pytest.fixture
def layout(tmp_path: Path) -> Layout:
    return Layout(tmp_path / "root")


@pytest.fixture
def folders(layout: Layout) -> AppFolders:
    store = MemoryStore(layout=layout, remotes={URL: {
        OLD: {"x": (TREE_OLD, {"start.sh": "old"})},
        NEW: {"x": (TREE_NEW, {"start.sh": "new", "stop.sh": ""})},
    }})
    store.fetch(KEY, URL)
    return DiskFolders(layout=layout, store=store)


def gen(generation: str = GEN_OLD, commit: str = OLD, tree: str = TREE_OLD) -> Generation:
    return Generation(name="x", generation=generation, repository=KEY, commit=commit,
                      path="x", tree=tree, params={"K": "1"})


def test_stage_is_idempotent_and_keeps_what_is_staged(folders: AppFolders) -> None:
    first = folders.stage(gen())
    (first / "start.sh").write_text("changed by install.sh")
    assert folders.stage(gen()) == first
    assert (first / "start.sh").read_text() == "changed by install.sh"
    assert folders.meta("x", GEN_OLD) == Generation(**{**gen().__dict__,
                                                       "scripts": ("start.sh",)})
    assert folders.present() == frozenset({GenerationKey("x", GEN_OLD)})


def test_stage_refuses_a_tree_that_is_not_the_planned_one(folders: AppFolders,
                                                          layout: Layout) -> None:
    with pytest.raises(StepError, match="not what was planned"):
        folders.stage(gen(tree=TREE_NEW))
    assert folders.present() == frozenset()
    assert not layout.generation_dir("x", GEN_OLD).exists()


def test_ensure_restores_a_missing_folder_from_the_store(folders: AppFolders) -> None:
    where = folders.stage(gen())
    (where / "start.sh").unlink()
    where.rmdir()
    assert folders.ensure(gen()) == where
    assert (where / "start.sh").read_text() == "old"


def test_ensure_refuses_a_tree_mismatch_and_an_unknown_origin(folders: AppFolders,
                                                              layout: Layout) -> None:
    with pytest.raises(StepError, match="not what was planned"):
        folders.ensure(gen(tree=TREE_NEW))
    with pytest.raises(StepError, match="does not know where it came from"):
        folders.ensure(Generation(name="x", generation=GEN_OLD))
    assert not layout.generation_dir("x", GEN_OLD).exists()


def test_point_makes_the_link_and_set_current_names_it(folders: AppFolders,
                                                       layout: Layout) -> None:
    layout.libpanda.mkdir(parents=True)
    manifest = layout.libpanda / "app"
    manifest.write_text("None\n")
    old, new = folders.stage(gen()), folders.stage(gen(GEN_NEW, NEW, TREE_NEW))
    link = folders.point("x", old)
    assert link == layout.app_link("x") and os.readlink(link) == str(old)
    assert folders.point("x", new) == link and os.readlink(link) == str(new)
    folders.set_current("x")
    assert manifest.read_text() == "x\n"
    folders.set_current(None)
    assert manifest.read_text() == "None\n"


def test_set_current_writes_nothing_without_lpams_manifest(folders: AppFolders,
                                                           layout: Layout) -> None:
    folders.set_current("x")
    assert not layout.libpanda.exists()


def test_point_moves_lpams_own_folder_aside(folders: AppFolders, layout: Layout) -> None:
    lpams = layout.app_link("x")
    lpams.mkdir(parents=True)
    (lpams / "service").write_text("lpam-x.service\n")
    assert folders.service_of(lpams) == "lpam-x"
    folders.point("x", folders.stage(gen()))
    assert lpams.is_symlink()
    assert any(layout.var.rglob("service"))  # moved, not deleted


def test_release_keeps_the_link_of_another_generation(folders: AppFolders,
                                                      layout: Layout) -> None:
    old, new = folders.stage(gen()), folders.stage(gen(GEN_NEW, NEW, TREE_NEW))
    link = folders.point("x", new)
    folders.release("x", old)
    assert os.readlink(link) == str(new)
    folders.release("x", new)
    assert not os.path.lexists(link)


def test_prune_keeps_what_it_is_told_and_installed_reads_the_rest(folders: AppFolders,
                                                                  layout: Layout) -> None:
    folders.stage(gen())
    folders.stage(gen(GEN_NEW, NEW, TREE_NEW))
    assert {g.generation for g in folders.installed()} == {GEN_OLD, GEN_NEW}
    folders.prune({GenerationKey("x", GEN_NEW)})
    assert folders.present() == frozenset({GenerationKey("x", GEN_NEW)})
    assert not layout.generation_meta("x", GEN_OLD).exists()
    assert [g.commit for g in folders.installed()] == [NEW]
    folders.prune(set())
    assert folders.installed() == [] and not (layout.generations / "x").exists()
