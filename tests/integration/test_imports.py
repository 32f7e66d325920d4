"""What each command loads: the heavy libraries stay out of the commands that do not need
them, so start-up on a Pi stays short. Imports inside functions exist for this (the
acyclic contract, tests/importcontracts.py, shows none of them dodges a cycle); a top-level
import that pulls a heavy library into `lpam --version` would slow every command silently,
and this test is what notices (issue 32: the typed plan once put pydantic under `--help`).

Each command runs in a fresh interpreter against its own `--root`; what it loaded is read
from `sys.modules` as the command returns. No timings: a loaded module is the regression.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from reconciler.base.layout import Layout
from reconciler.engine.records.state import write_record
from reconciler.frontends.cli import COMMANDS
from schemas.record import AppRecord, RepositoryRecord, StateRecord
from tests.gitserver import git_env, run_git

HEAVY = ("pydantic", "ruamel", "dulwich", "networkx", "can", "cantools", "dbus_fast")
PROBE = """
import importlib, json, sys
face, runs = sys.argv[1], json.loads(sys.argv[2])
main = importlib.import_module(face).main
for argv in runs:
    try:
        main(argv)
    except SystemExit:
        pass
sys.stderr.write("\\nLOADED " + json.dumps(sorted(set(m.split(".")[0] for m in sys.modules))))
"""
CLI, SHIM = "reconciler.frontends.cli", "reconciler.frontends.shim"
CATALOG = "apps:\n  - name: alpha\n    path: alpha/\n  - name: beta\n"


def probe(face: str, *runs: list[str], env: dict[str, str] | None = None
          ) -> tuple[set[str], str]:
    """The heavy top-level packages one interpreter loaded running `face`'s main on each
    argument list in turn, and what it printed."""
    done = subprocess.run([sys.executable, "-c", PROBE, face, json.dumps(runs)],
                          capture_output=True, text=True, timeout=120, check=False, env=env)
    line = done.stderr.rsplit("\nLOADED ", 1)
    assert len(line) == 2, done.stderr
    return set(json.loads(line[1])) & set(HEAVY), done.stdout


def loaded(root: Path, *args: str) -> set[str]:
    """The heavy top-level packages `lpam --root ROOT ARGS` loaded."""
    return probe(CLI, ["--root", str(root), *args])[0]


@pytest.fixture
def applied(tmp_path: Path, hermetic_env: Path) -> Layout:
    """A root as an apply leaves it, made without one: a checkout of the repository `apps`
    in the store (real git objects, loose and packed) and a state record that installed
    alpha from its commit."""
    layout = Layout(tmp_path / "root")
    work, env = layout.repository_dir("apps"), git_env(hermetic_env)
    work.mkdir(parents=True)
    run_git("init", "--quiet", cwd=work, env=env)
    for path, text in {"libpanda-apps.yaml": CATALOG, "alpha/description.txt": "the alpha app",
                       "alpha/service": "can", "beta/description.txt": "the beta app"}.items():
        (work / path).parent.mkdir(exist_ok=True)
        (work / path).write_text(text + "\n")
    run_git("add", "--all", cwd=work, env=env)
    run_git("commit", "--quiet", "-m", "alpha and beta", cwd=work, env=env)
    run_git("gc", "--quiet", cwd=work, env=env)  # packed, as a fetch leaves them
    run_git("commit", "--quiet", "--allow-empty", "-m", "loose", cwd=work, env=env)
    commit = run_git("rev-parse", "HEAD", cwd=work, env=env)
    write_record(layout, StateRecord(
        repositories=[RepositoryRecord(key="apps", url="git://x/apps.git", ref=None,
                                       commit=commit, applied=commit)],
        apps=[AppRecord(name="alpha", repository="apps", commit=commit, tree="t" * 40,
                        path="alpha/", generation="g1", status="running")]))
    desired = layout.desired_state  # what the shim lists: the same repository
    desired.parent.mkdir(parents=True, exist_ok=True)
    desired.write_text(f"version: 2\nrepositories:\n  - url: {work}\n    ref: {commit}\n"
                       "apps:\n  - name: alpha\n")
    return layout


@pytest.fixture
def empty_desired(tmp_path: Path) -> Path:
    path = tmp_path / "desired-state.yaml"
    path.write_text("version: 2\nrepositories: []\napps: []\n")
    return path


def test_version_and_help_load_no_heavy_library(tmp_path: Path) -> None:
    """`--version`, `--help` and every command's `--help` (`lpam ble pair --help` too):
    argparse only, whatever the command would load to run."""
    root = ["--root", str(tmp_path / "root")]
    assert probe(CLI, [*root, "--version"])[0] == set()
    assert probe(CLI, [*root, "--help"])[0] == set()
    helps = [[*root, *command.split(), "--help"] for command in [*COMMANDS, "ble pair"]]
    assert probe(CLI, *helps)[0] == set()


def test_status_of_an_applied_root_loads_no_git_library_and_no_graph(applied: Layout) -> None:
    """Status reads the committed catalog and app files without dulwich
    (adapters/objectfiles.py), and plans nothing: no graph. The table and `--json` say what
    was read, so the catalog was read indeed."""
    root = ["--root", str(applied.root)]
    found, said = probe(CLI, [*root, "status"])
    assert found.isdisjoint({"dulwich", "networkx", "can", "cantools", "dbus_fast"}), found
    assert "the alpha app" in said and "the beta app" in said, said
    found, said = probe(CLI, [*root, "status", "--json"])
    assert found.isdisjoint({"dulwich", "networkx", "can", "cantools", "dbus_fast"}), found
    assert {a["app"] for a in json.loads(said)["apps"]} == {"alpha", "beta"}


def test_status_of_an_empty_root_loads_no_yaml_either(tmp_path: Path) -> None:
    found = loaded(tmp_path / "root", "status")
    assert found.isdisjoint({"dulwich", "networkx", "can", "cantools", "dbus_fast",
                             "ruamel"}), found


def test_the_shims_help_loads_no_heavy_library(applied: Layout) -> None:
    env = {**os.environ, "LPAM_ROOT": str(applied.root)}
    assert probe(SHIM, ["-h"], env=env)[0] == set()


@pytest.mark.parametrize("flag", ["-d", "-l", "-c", "-t"])
def test_the_shims_reading_flags_load_no_graph(applied: Layout, flag: str) -> None:
    env = {**os.environ, "LPAM_ROOT": str(applied.root)}
    found, said = probe(SHIM, [flag], env=env)
    assert found.isdisjoint({"networkx", "can", "cantools", "dbus_fast"}), found
    assert "alpha" in said, said


def test_the_shims_reading_flags_load_no_git_library(applied: Layout) -> None:
    """The shim resolves the desired state offline, checks each copy and reads the
    committed files from git's own files (adapters/objectfiles.py, adapters/gitfiles.py,
    adapters/integrity.py): no dulwich, and still every row."""
    env = {**os.environ, "LPAM_ROOT": str(applied.root)}
    found, said = probe(SHIM, ["-d"], ["-l"], ["-c"], ["-t"], env=env)
    assert "dulwich" not in found, found
    assert "the alpha app" in said and "the beta app" in said, said


def test_a_plan_in_order_loads_no_graph_library(tmp_path: Path, empty_desired: Path) -> None:
    """A plan whose steps are already in order needs no graph (core/planning/graph.py's
    fast path); no CAN or D-Bus either without gates or the phone."""
    found = loaded(tmp_path / "root", "plan", "-f", str(empty_desired))
    assert found.isdisjoint({"networkx", "can", "cantools", "dbus_fast"}), found
    assert "pydantic" in found  # it did plan: the document was read
