"""What each command loads: the heavy libraries stay out of the commands that do not need
them, so start-up on a Pi stays short. Imports inside functions exist for this (the
acyclic contract, tests/importcontracts.py, shows none of them dodges a cycle); a top-level
import that pulls a heavy library into `lpam --version` would slow every command silently,
and this test is what notices.

Each command runs in a fresh interpreter against its own `--root`.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("pydantic", "ruamel", "dulwich", "networkx", "can", "cantools", "dbus_fast")
PROBE = """
import json, sys
from reconciler.frontends.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
sys.stderr.write("\\nLOADED " + json.dumps(sorted(set(m.split(".")[0] for m in sys.modules))))
"""


def loaded(root: Path, *args: str) -> set[str]:
    """The heavy top-level packages `lpam --root ROOT ARGS` loaded."""
    done = subprocess.run([sys.executable, "-c", PROBE, "--root", str(root), *args],
                          capture_output=True, text=True, timeout=120, check=False)
    line = done.stderr.rsplit("\nLOADED ", 1)
    assert len(line) == 2, done.stderr
    return set(json.loads(line[1])) & set(HEAVY)


@pytest.fixture
def empty_desired(tmp_path: Path) -> Path:
    path = tmp_path / "desired-state.yaml"
    path.write_text("version: 2\nrepositories: []\napps: []\n")
    return path


def test_version_and_help_load_no_heavy_library(tmp_path: Path) -> None:
    assert loaded(tmp_path / "root", "--version") == set()
    assert loaded(tmp_path / "root", "--help") == set()


def test_status_loads_neither_the_graph_nor_a_bus(tmp_path: Path) -> None:
    found = loaded(tmp_path / "root", "status")
    assert found.isdisjoint({"networkx", "can", "cantools", "dbus_fast", "ruamel"}), found


def test_a_plan_in_order_loads_no_graph_library(tmp_path: Path, empty_desired: Path) -> None:
    """A plan whose steps are already in order needs no graph (core/planning/graph.py's
    fast path); no CAN or D-Bus either without gates or the phone."""
    found = loaded(tmp_path / "root", "plan", "-f", str(empty_desired))
    assert found.isdisjoint({"networkx", "can", "cantools", "dbus_fast"}), found
    assert "pydantic" in found  # it did plan: the document was read
