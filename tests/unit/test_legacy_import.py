"""Importing an LPAM directory of every era, from fixtures built in a temporary folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import migrations
from reconciler.base.errors import ConfigError, VersionError
from reconciler.base.loading import load
from reconciler.engine.records.legacy import (
    branch_of_head,
    import_lpam,
    parse_app_file,
    parse_manifest_csv,
    parse_ros_csv,
)
from schemas.desired import DesiredState

FIXTURES = Path(migrations.__file__).parent / "fixtures" / "lpam"
BEFORES = sorted(FIXTURES.glob("*.before.yaml"))


def build(root: Path, spec: dict[str, Any]) -> Path:
    """Write a `files:`/`dirs:` fixture as a real LPAM directory under `root`."""
    etc = root / "libpanda.d"
    etc.mkdir(parents=True)
    for name in spec.get("dirs", []):
        (etc / name).mkdir(parents=True)
    for name, text in spec.get("files", {}).items():
        path = etc / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(text.encode("utf-8"))
    return etc


def build_files(root: Path, files: dict[str, str]) -> Path:
    return build(root, {"files": files})


def run(etc: Path) -> tuple[str, dict[str, Any]]:
    """Import; return the comment header as one line of prose, and the validated document."""
    text = import_lpam(etc)
    header = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        header.append(" ".join(line[1:].split()))
    data = load(etc / "out.yaml", text).data
    DesiredState.model_validate(migrations.upgrade("desired-state", data, path=etc / "out.yaml"))
    return " ".join(header), data


@pytest.mark.parametrize("before", BEFORES, ids=lambda p: p.name.split(".")[0])
def test_each_era_imports_as_its_fixture(before: Path, tmp_path: Path) -> None:
    etc = build(tmp_path, load(before).data)
    after = load(before.with_name(before.name.replace(".before.", ".after."))).data
    _, data = run(etc)
    assert data == after


def test_every_era_has_a_fixture() -> None:
    names = {p.name.split("-")[0] for p in BEFORES}
    assert {"era1", "era2", "era3", "era4", "mixed"} <= names


def test_output_is_commented_yaml_and_deterministic(tmp_path: Path) -> None:
    etc = build(tmp_path, load(FIXTURES / "era4-manifest.before.yaml").data)
    text = import_lpam(etc)
    assert text == import_lpam(etc)
    assert text.startswith("# Desired state imported from LPAM")
    header, _ = run(etc)  # the note wraps at 92 columns: a long path goes to the next line
    assert f"LPAM directory: {etc}" in header
    assert "version: 1\n" in text


def test_era1_header_explains_where_repositories_came_from(tmp_path: Path) -> None:
    text, _ = run(build(tmp_path, load(FIXTURES / "era1-clones.before.yaml").data))
    assert "2023-04" in text
    assert "apps-repositories/" in text
    assert "detached at 3f8a36192d41b7d454e9f787ff61b99f287e3e0d" in text
    assert "Apps found under apps/: cbf, mvt, pandarecord" in text
    # ROS pins are reported, capitalised owner and all, but never imported.
    assert "apps/cbf/rosRepositories.csv" in text
    assert "Jmscslgroup/setpointreader at bf9116d7e7a8284527e1d94537de1228c2b3abb8" in text
    assert "not app repositories" in text


def test_era1_without_clones_says_repositories_are_unknown(tmp_path: Path) -> None:
    header, data = run(build(tmp_path, load(FIXTURES / "era1-bare.before.yaml").data))
    assert data["repositories"] == []
    assert "`repositories` is empty" in header
    assert "MatthewNice/joy_to_veh at 6c2601c2c1ec394d937b2685c4b2f2072ce970d8" in header


def test_newest_era_wins_and_ignored_files_are_named(tmp_path: Path) -> None:
    header, data = run(build(tmp_path, load(FIXTURES / "mixed-eras.before.yaml").data))
    assert (
        "Ignored (older LPAM formats; the newest wins): app-manifest.csv, app, "
        "app-manifest.yaml.bak Apps found" in header
    )
    assert data["app"] is None  # `current: None` beats the stale `app` file's mvt
    assert "old" not in str(data)


def test_csv_beats_app_only_era(tmp_path: Path) -> None:
    etc = build_files(tmp_path, {"app-manifest.csv": "a/b, main\n", "app": "x\n"})
    header, data = run(etc)
    assert data == {"version": 1, "repositories": [{"repo": "a/b", "ref": "main"}], "app": "x"}
    assert "Ignored" not in header


def test_era3_app_comes_from_the_app_file(tmp_path: Path) -> None:
    etc = build_files(tmp_path, {"app-manifest.yaml": "a/b: {branch: main}\n", "app": "cbf\n"})
    _, data = run(etc)
    assert data["app"] == "cbf"


def test_empty_yaml_manifest_is_era3_with_no_repositories(tmp_path: Path) -> None:
    _, data = run(build_files(tmp_path, {"app-manifest.yaml": "\n", "app": "None\n"}))
    assert data == {"version": 1, "repositories": [], "app": None}


def test_clone_notes_for_manifest_eras(tmp_path: Path) -> None:
    etc = build(tmp_path, {"files": {
        "app-manifest.csv": "a/b, main\n",
        "apps-repositories/a/b/.git/HEAD": "ref: refs/heads/dev\n",
        "apps-repositories/c/d/.git/HEAD": "ref: refs/heads/main\n",
    }})
    text, data = run(etc)
    assert data["repositories"] == [{"repo": "a/b", "ref": "main"}]
    assert "apps-repositories/a/b is checked out at dev; the manifest says main" in text
    assert "apps-repositories/c/d is cloned but not in the manifest" in text


def test_odd_folder_names_cannot_break_the_yaml(tmp_path: Path) -> None:
    etc = build(tmp_path, {"files": {"app": "None\n"}, "dirs": ["apps/x\x01y", "apps/a\nb"]})
    header, _ = run(etc)
    assert "'x\\x01y'" in header


# --- the pure parsers ---------------------------------------------------------------------


def test_parse_manifest_csv_messy_spacing() -> None:
    text = "\n a/b ,main\r\n\n\tc/d,\t dev\t\n# a comment\ne/f,\n"
    repos, notes = parse_manifest_csv(text, Path("m.csv"))
    assert repos == [{"repo": "a/b", "ref": "main"}, {"repo": "c/d", "ref": "dev"},
                     {"repo": "e/f"}]
    assert notes == []


def test_parse_manifest_csv_repeated_repository_last_line_wins() -> None:
    repos, notes = parse_manifest_csv("a/b, main\nc/d, x\na/b, dev\n", Path("m.csv"))
    assert repos == [{"repo": "c/d", "ref": "x"}, {"repo": "a/b", "ref": "dev"}]
    assert notes == ["app-manifest.csv lists a/b again on line 3; that line wins"]


def test_parse_app_file() -> None:
    assert parse_app_file("None\n", Path("app")) is None
    assert parse_app_file("\n  pandarecord \n\n", Path("app")) == "pandarecord"
    assert parse_app_file("", Path("app")) is None


@pytest.mark.parametrize(
    ("head", "ref"),
    [
        ("ref: refs/heads/main\n", "main"),
        ("ref: refs/heads/feature/x\n", "feature/x"),
        ("49f281a3718c927b6e2624f0679854347c76105b\n", "49f281a3718c927b6e2624f0679854347c76105b"),
        ("ref: refs/heads/a..b\n", None),
        ("ref: refs/tags/v1\n", None),
        (None, None),
        ("garbage", None),
    ],
)
def test_branch_of_head(head: str | None, ref: str | None) -> None:
    assert branch_of_head(head)[0] == ref


def test_parse_ros_csv_tabs_case_and_bad_lines() -> None:
    text = ("jmscslgroup,\t   can_to_ros,\t\t7f81b03c\r\n\n"
            "Jmscslgroup,\t   setpointreader, bf9116d7\nonly, two\n")
    pins, bad = parse_ros_csv(text)
    assert pins == [(1, "jmscslgroup/can_to_ros", "7f81b03c"),
                    (3, "Jmscslgroup/setpointreader", "bf9116d7")]
    assert bad == [4]


# --- bad input: a ConfigError at the faulty spot, never a traceback ------------------------


def test_missing_etc_dir(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        import_lpam(tmp_path / "nope")
    assert info.value.path == tmp_path / "nope"
    assert info.value.hint and "/etc/libpanda.d" in info.value.hint


def test_etc_dir_is_a_file(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("x")
    with pytest.raises(ConfigError, match="not a directory"):
        import_lpam(tmp_path / "f")


def test_no_lpam_files(tmp_path: Path) -> None:
    (tmp_path / "unrelated.txt").write_text("x")
    with pytest.raises(ConfigError) as info:
        import_lpam(tmp_path)
    assert "no LPAM files" in info.value.message
    assert info.value.path == tmp_path
    assert info.value.hint


@pytest.mark.parametrize(
    ("csv", "line", "column", "words"),
    [
        ("a/b, main\n\n../x, main\n", 3, 1, "'../x'"),
        ("a/b, main\n  a;rm -rf, main\n", 2, 3, "'a;rm -rf'"),
        ("a/b,\tma in\n", 1, 6, "branch"),
        ("a/b, main, extra\n", 1, 12, "3 fields"),
        ("  , main\n", 1, 3, "nothing"),
        ("owner/repo/extra, main\n", 1, 1, "repository name"),
        ("a/b, $(reboot)\n", 1, 6, "branch"),
    ],
)
def test_bad_csv_line(tmp_path: Path, csv: str, line: int, column: int, words: str) -> None:
    etc = build_files(tmp_path, {"app-manifest.csv": csv})
    with pytest.raises(ConfigError) as info:
        import_lpam(etc)
    error = info.value
    assert (error.path, error.line, error.column) == (etc / "app-manifest.csv", line, column)
    assert words in error.message
    assert error.hint


@pytest.mark.parametrize(
    ("yaml", "line", "column", "words"),
    [
        ("a/b: {branch: main}\n../x:\n  branch: main\n", 2, 1, "'../x'"),
        ("a/b:\n  branch: 'a;b'\n", 2, 3, "branch"),
        ("version: 0.0\nrepositories:\n  'a;rm -rf/x': {branch: main}\n", 3, 3, "a;rm -rf"),
        ("version: 0.0\nrepositories: {}\ncurrent: ../etc\n", 3, 1, "app name"),
        ("repositories:\n  a/b: {branch: main}\ncurrent: None\n", 1, 1, "without `version:`"),
        ("a/b: [\n", 2, 1, ""),
        ("a/b:\n\tbranch: main\n", 2, 1, "tab"),
        ("- a/b\n", 1, 1, "expected a map"),
    ],
)
def test_bad_yaml_manifest(tmp_path: Path, yaml: str, line: int, column: int, words: str) -> None:
    etc = build_files(tmp_path, {"app-manifest.yaml": yaml, "app": "None\n"})
    with pytest.raises(ConfigError) as info:
        import_lpam(etc)
    error = info.value
    assert (error.path, error.line, error.column) == (etc / "app-manifest.yaml", line, column)
    assert words in error.message
    assert error.hint


def test_a_desired_state_is_not_imported_again(tmp_path: Path) -> None:
    etc = build_files(tmp_path, {"app-manifest.yaml": "app: x\nversion: 1\n"})
    with pytest.raises(ConfigError, match="already an lpam desired state") as info:
        import_lpam(etc)
    assert (info.value.line, info.value.column) == (2, 1)


def test_newer_manifest_version_is_refused(tmp_path: Path) -> None:
    etc = build_files(tmp_path, {"app-manifest.yaml": "version: 3\n"})
    with pytest.raises(VersionError, match="document version 3, this lpam reads up to 2"):
        import_lpam(etc)


@pytest.mark.parametrize(
    ("app", "line", "column"),
    [("../evil\n", 1, 1), ("\n  bad name\n", 2, 3), ("cbf\nmvt\n", 2, 1), ("a;reboot", 1, 1)],
)
def test_bad_app_file(tmp_path: Path, app: str, line: int, column: int) -> None:
    etc = build_files(tmp_path, {"app": app})
    with pytest.raises(ConfigError) as info:
        import_lpam(etc)
    assert (info.value.path, info.value.line, info.value.column) == (etc / "app", line, column)
    assert info.value.hint


def test_bad_clone_folder_name(tmp_path: Path) -> None:
    etc = build(tmp_path, {"files": {"app": "None\n"}, "dirs": ["apps-repositories/a;rm -rf/x"]})
    with pytest.raises(ConfigError) as info:
        import_lpam(etc)
    assert info.value.path == etc / "apps-repositories" / "a;rm -rf" / "x"


def test_binary_and_non_utf8_files(tmp_path: Path) -> None:
    etc = build_files(tmp_path, {"app": "x"})
    (etc / "app-manifest.csv").write_bytes(b"a/b, main\n\xff\xfe\n")
    with pytest.raises(ConfigError) as info:
        import_lpam(etc)
    assert (info.value.line, info.value.message) == (2, "file is not UTF-8 text")
    (etc / "app-manifest.csv").write_bytes(b"a/b\x00")
    with pytest.raises(ConfigError, match="binary"):
        import_lpam(etc)


NASTY = ["", "\n", ":", "- - -", "{", "version: [", "a/b: 1\n", "a/b: true", "a/b: {branch: 1}",
         "version: 0.0\nrepositories: 5", "version: 0.0\ncurrent: 5", ",,,,", "x" * 300,
         "version: 0.0\nrepositories:\n  a/b: {branch: {x: 1}}", "\ufeffa/b, main", "&a [*a]",
         "version: 0.0\nrepositories:\n  1: {}", "!!python/object:os.system {}"]


@pytest.mark.parametrize("name", ["app-manifest.yaml", "app-manifest.csv", "app"])
def test_nothing_but_config_errors_for_garbage(tmp_path: Path, name: str) -> None:
    for index, text in enumerate(NASTY):
        etc = build(tmp_path / str(index), {"files": {name: text}})
        try:
            _, data = run(etc)
        except ConfigError as exc:
            assert exc.path is not None and exc.path.is_relative_to(etc)
        else:
            assert data["version"] == 1
