"""Desired-state documents: every fault named at file:line:column with a hint."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError, VersionError
from reconciler.core.documents import load_desired, parse_catalog
from schemas.desired import DesiredState
from schemas.export import FOLDER, rendered

REFERENCE = Path(__file__).resolve().parents[1] / "fixtures"
TOP = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str | bytes) -> Path:
    path = tmp_path / "desired.yaml"
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


def error_of(tmp_path: Path, text: str | bytes) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_desired(write(tmp_path, text))
    return info.value


def test_full_and_shorthand_forms(tmp_path: Path) -> None:
    state = load_desired(write(tmp_path, """\
version: 1
repositories:
  - repo: jmscslgroup/libpanda-default-apps
  - url: git://127.0.0.1:9418/other.git
    ref: v1.0
app: {name: cbf, repository: jmscslgroup/libpanda-default-apps, params: {RATE: "10"}}
"""))
    keys = [r.key for r in state.repositories]
    assert keys == ["jmscslgroup/libpanda-default-apps", "other"]
    assert state.repositories[0].source(tmp_path) == (
        "https://github.com/jmscslgroup/libpanda-default-apps")
    assert [a.params for a in state.apps] == [{"RATE": "10"}]
    short = load_desired(write(tmp_path, "version: 1\napp: pandarecord\n"))
    assert [a.name for a in short.apps] == ["pandarecord"]
    assert load_desired(write(tmp_path, "version: 1\napp: null\n")).apps == []


def test_relative_path_is_relative_to_the_document(tmp_path: Path) -> None:
    state = load_desired(write(tmp_path, "version: 1\nrepositories:\n  - url: repos/apps.git\n"))
    assert state.repositories[0].source(tmp_path) == str(tmp_path / "repos" / "apps.git")


def test_example_desired_state_is_valid() -> None:
    state = load_desired(TOP / "desired-state.example.yaml")
    assert [a.name for a in state.apps] == ["can-logger"]


@pytest.mark.parametrize(
    ("text", "line", "column", "words"),
    [
        ("version: 1\nrepositories:\n  - url: x\n    reff: main\n", 4, 5, "unknown key 'reff'"),
        ("version: 1\napp:\n  name: x\n  params: {RATE: 10}\n", 4, 12, "quote the value"),
        ("version: 1\nversion: 1\n", 2, 1, "duplicate key"),
        ("version: 1\napp:\n\tname: x\n", 3, 1, "tab"),
        ("version: 1\nrepositories: [\n", 3, 1, ""),
        ("version: 1\napp: ../etc\n", 2, 1, "app names"),
        ("version: 1\napp: a/b\n", 2, 1, "app names"),
        ("version: 1\nrepositories:\n  - url: 'x; rm -rf /'\n", 3, 5, "metacharacter"),
        ("version: 1\nrepositories:\n  - url: --upload-pack=evil\n", 3, 5, "start with '-'"),
        ("version: 1\nrepositories:\n  - repo: a/b\n    ref: -x\n", 4, 5, "ref"),
        ("version: 1\nrepositories:\n  - repo: a/b\n    ref: 'main;reboot'\n", 4, 5, "ref"),
        ("version: 1\nrepositories:\n  - repo: a/b\n  - repo: a/b\n", 4, 5, "listed twice"),
        ("version: 1\nrepositories:\n  - repo: a/b\n    url: x\n", 3, 5, "exactly one"),
        ("version: 1\nrepositories: {a: b}\n", 2, 1, "list"),
    ],
)
def test_bad_documents_name_line_and_column(
    tmp_path: Path, text: str, line: int, column: int, words: str
) -> None:
    error = error_of(tmp_path, text)
    assert (error.line, error.column) == (line, column), error.render()
    assert words.lower() in error.render().lower()
    assert error.render().startswith(f"error: {tmp_path / 'desired.yaml'}:{line}:{column}: ")


@pytest.mark.parametrize(
    ("content", "words"),
    [(b"", "empty"), (b"  \n", "empty"), (b"\x00\x01\x02binary", "binary"),
     (b"\xff\xfe bad", "UTF-8")],
)
def test_empty_binary_and_undecodable_files(tmp_path: Path, content: bytes, words: str) -> None:
    assert words in error_of(tmp_path, content).render()


def test_newer_version_is_refused_naming_both(tmp_path: Path) -> None:
    with pytest.raises(VersionError) as info:
        load_desired(write(tmp_path, "version: 7\n"))
    assert "7" in info.value.render() and "1" in info.value.render()


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="file not found"):
        load_desired(tmp_path / "nope.yaml")


def test_both_catalog_shapes_normalise() -> None:
    real = parse_catalog(REFERENCE / "x.yaml",
                         (REFERENCE / "libpanda-default-apps.libpanda-apps.yaml").read_text())
    cbf = real.app("cbf")
    assert cbf is not None and cbf.path == "cbf" and cbf.owns_panda
    assert [r.repo for r in cbf.ros_repositories][:2] == ["can_to_ros", "cbf"]
    joy = real.app("joy_to_veh")
    assert joy is not None and joy.apt == ["libdiagnostic-updater-dev"] and joy.path == "joy_to_veh"
    assert joy.ros_repositories[-1].ref is None
    paper = parse_catalog(Path("paper.yaml"), """\
apps:
  - name: joy2veh
    properties:
      dependencies: [{apt: libdiagnostic-updater-dev}, {pip3: numpy}]
      ros_repositories:
        - {owner: jmscslgroup, repo: can_to_ros, branch_or_hash: 17dd12e9}
""")
    j2v = paper.app("joy2veh")
    assert j2v is not None and j2v.pip3 == ["numpy"] and j2v.ros_repositories[0].ref == "17dd12e9"


def test_catalog_errors_have_positions() -> None:
    with pytest.raises(ConfigError) as info:
        parse_catalog(Path("c.yaml"), "apps:\n  - name: x\n    path: ../../etc\n")
    assert (info.value.line, info.value.column) == (3, 5)
    with pytest.raises(ConfigError, match="twice"):
        parse_catalog(Path("c.yaml"), "apps:\n  - name: x\n  - name: x\n")


def test_committed_json_schemas_match_the_models() -> None:
    for name, text in rendered().items():
        assert (FOLDER / name).read_text() == text, f"run `python -m schemas.export` ({name})"
    assert "repositories" in DesiredState.model_json_schema()["properties"]


def test_two_local_repositories_with_one_folder_name_need_a_name(tmp_path: Path) -> None:
    clash = "version: 1\nrepositories:\n  - url: /a/apps.git\n  - url: /b/apps.git\n"
    assert "distinct `name:`" in error_of(tmp_path, clash).render()
    named = load_desired(write(tmp_path, clash + "    name: lab-apps\napp:\n  name: x\n"
                                         "  repository: lab-apps\n"))
    assert [r.key for r in named.repositories] == ["apps", "lab-apps"]
    assert named.repository("lab-apps") is named.repositories[1]
