"""The metadata file beside each generation is a versioned document: what an older lpam
wrote (no version) is still read, what a newer one wrote or what is not metadata at all
is not (read_meta says None, and lpam falls back on the state record, as it always did)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import cast

import pytest

from reconciler.adapters.memory import MemoryStore
from reconciler.base.layout import Layout
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps.folders import as_record, staged
from reconciler.engine.records import generations
from reconciler.engine.records.generations import Generation, read_meta
from schemas.generation import AppGeneration, GenerationMeta
from schemas.record import AppRecord

GEN = "0123456789ab-01234567"
URL, KEY, COMMIT, TREE = "git://h/apps", "lab/apps", "a" * 40, "1" * 40


def write(tmp_path: Path, body: object) -> Path:
    path = tmp_path / f"{GEN}.json"
    path.write_text(json.dumps(body))
    return path


def test_an_unversioned_file_of_an_older_lpam_is_read(tmp_path: Path) -> None:
    meta = read_meta(write(tmp_path, {"app": "x", "generation": GEN, "params": {"K": "1"},
                                      "scripts": ["start.sh"], "venv": "/v"}))
    assert meta == Generation(name="x", generation=GEN, params={"K": "1"},
                              scripts=("start.sh",), venv="/v")


@pytest.mark.parametrize("body", [
    {"version": 2, "name": "x", "generation": GEN},  # a newer lpam's
    {"version": 1, "generation": GEN},  # no app
    {"app": "x", "generation": GEN, "params": ["K"]},
    {"app": "x", "name": "y", "generation": GEN},
    ["x"], "x", None,
])
def test_what_is_not_metadata_this_lpam_reads_is_none(tmp_path: Path, body: object) -> None:
    assert read_meta(write(tmp_path, body)) is None


def test_a_staged_generation_writes_version_1_and_reads_it_back(tmp_path: Path) -> None:
    layout = Layout(tmp_path / "root")
    store = MemoryStore(layout=layout, remotes={URL: {COMMIT: {"x": (TREE, {"start.sh": ""})}}})
    store.fetch(KEY, URL)
    gen = Generation(name="x", generation=GEN, repository=KEY, commit=COMMIT, path="x",
                     tree=TREE, params={"K": "1"}, command=("run",), ros={"r": "c"},
                     ros_build="b", venv="/v")
    generations.stage(layout, store, gen)
    path = layout.generation_meta("x", GEN)
    written = json.loads(path.read_text())
    assert written["version"] == 1 and written["name"] == "x" and "app" not in written
    GenerationMeta.model_validate(written)
    assert read_meta(path) == Generation(**{**gen.__dict__, "scripts": ("start.sh",)})


GOLDEN = """{
  "command": [
    "run"
  ],
  "commit": "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa",
  "generation": "0123456789ab-01234567",
  "launch": null,
  "name": "x",
  "params": {
    "K": "1"
  },
  "path": "x",
  "repository": "lab/apps",
  "ros": {
    "r": "c"
  },
  "ros_build": "b",
  "ros_user": null,
  "ros_workspace": null,
  "scripts": [
    "start.sh"
  ],
  "service": "lpam-app-x",
  "tree": "1111111111111111111111111111111111111111",
  "user": null,
  "venv": "/v",
  "version": 1
}
"""


def test_a_step_s_generation_is_staged_as_the_very_file_older_lpams_wrote(
        tmp_path: Path) -> None:
    """The metadata file is what a lost record falls back on, and lpam's older versions
    read it too: the same generation must write the same bytes, whatever model the engine
    holds it in (the text is what lpam wrote before the engine used GenerationMeta)."""
    layout = Layout(tmp_path / "root")
    store = MemoryStore(layout=layout, remotes={URL: {COMMIT: {"x": (TREE, {"start.sh": ""})}}})
    store.fetch(KEY, URL)
    step = AppGeneration(name="x", generation=GEN, repository=KEY, commit=COMMIT, path="x",
                         tree=TREE, params={"K": "1"}, service="ignored: lpam writes its unit",
                         command=["run"], user="someone", ros={"r": "c"}, ros_build="b")
    gen = staged(step, "s1", cast(Context, None)).model_copy(update={"venv": "/v"})
    generations.stage(layout, store, gen)
    assert layout.generation_meta("x", GEN).read_text() == GOLDEN


def test_a_step_s_generation_becomes_the_record_s_app() -> None:
    """A step's generation and the record's app carry the same values (the user is the
    record's alone): recording an installed generation loses nothing the steps use."""
    step = AppGeneration(name="x", generation=GEN, repository=KEY, commit=COMMIT, path="x",
                         tree=TREE, params={"K": "1"}, launch="p/a.launch", user="u")
    gen = staged(step, "s1", cast(Context, None))
    assert gen.service == "lpam-app-x" and gen.folder == "x" and gen.user is None
    app = as_record(gen, "u")
    assert app == AppRecord(name="x", generation=GEN, repository=KEY, commit=COMMIT,
                            path="x", tree=TREE, params={"K": "1"}, launch="p/a.launch",
                            service="lpam-app-x", user="u")
