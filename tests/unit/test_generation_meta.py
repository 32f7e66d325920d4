"""The metadata file beside each generation is a versioned document: what an older lpam
wrote (no version) is still read, what a newer one wrote or what is not metadata at all
is not (read_meta says None, and lpam falls back on the state record, as it always did)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from reconciler import generations
from reconciler.adapters.memory import MemoryStore
from reconciler.generations import Generation, read_meta
from reconciler.layout import Layout
from schemas.generation import GenerationMeta

GEN = "0123456789ab-01234567"
URL, KEY, COMMIT, TREE = "git://h/apps", "lab/apps", "a" * 40, "1" * 40


def write(tmp_path: Path, body: object) -> Path:
    path = tmp_path / f"{GEN}.json"
    path.write_text(json.dumps(body))
    return path


def test_an_unversioned_file_of_an_older_lpam_is_read(tmp_path: Path) -> None:
    meta = read_meta(write(tmp_path, {"app": "x", "generation": GEN, "params": {"K": "1"},
                                      "scripts": ["start.sh"], "venv": "/v"}))
    assert meta == Generation(app="x", generation=GEN, params={"K": "1"},
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
    gen = Generation(app="x", generation=GEN, repository=KEY, commit=COMMIT, path="x",
                     tree=TREE, params={"K": "1"}, command=("run",), ros={"r": "c"},
                     ros_build="b", venv="/v")
    generations.stage(layout, store, gen)
    path = layout.generation_meta("x", GEN)
    written = json.loads(path.read_text())
    assert written["version"] == 1 and written["name"] == "x" and "app" not in written
    GenerationMeta.model_validate(written)
    assert read_meta(path) == Generation(**{**gen.__dict__, "scripts": ("start.sh",)})
