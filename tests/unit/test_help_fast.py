"""`lpam --help` is answered from help.txt before the CLI is imported, and says exactly what
argparse says; a terminal too narrow for that text gets argparse's own, wrapped to fit."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from reconciler.frontends import helptext

PROBE = ("import sys; sys.argv = ['lpam'] + sys.argv[1:]\n"
         "from reconciler.__main__ import main\n"
         "try:\n    code = main()\nexcept SystemExit as exc:\n    code = exc.code\n"
         "sys.stderr.write('%s %s %s' % (code, 'reconciler.frontends.cli' in sys.modules,\n"
         "                                'argparse' in sys.modules))")


def lpam(*args: str, columns: str | None = None) -> tuple[str, str]:
    """What `lpam ARGS` printed (not on a terminal: a pipe, as a pager reads it) and whether
    it had imported the CLI and argparse by the time it returned."""
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    if columns is not None:
        env["COLUMNS"] = columns
    done = subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True,
                          text=True, check=True, timeout=60, env=env)
    return done.stdout, done.stderr.strip()


def test_help_txt_is_what_the_parser_says() -> None:
    assert Path(helptext.FILE).read_text(encoding="utf-8") == helptext.rendered(), (
        "reconciler/frontends/help.txt is stale: run "
        "`python -m reconciler.frontends.helptext` and commit it")


@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_help_imports_no_cli_and_prints_the_text(flag: str) -> None:
    said, verdict = lpam(flag)
    assert verdict == "0 False False"
    assert said == helptext.rendered()
    assert "plan " in said and "apply " in said and "--root ROOT" in said


def test_a_narrow_terminal_gets_argparse_wrapped_to_fit() -> None:
    said, verdict = lpam("--help", columns="50")
    assert verdict == "0 True True"  # argparse said it
    assert said.startswith("usage: lpam")
    assert max(len(line) for line in said.splitlines()) <= 50
    assert said != helptext.rendered()


def test_a_copy_without_help_txt_asks_argparse(monkeypatch: pytest.MonkeyPatch,
                                                tmp_path: Path) -> None:
    monkeypatch.setattr(helptext, "FILE", str(tmp_path / "gone.txt"))
    monkeypatch.delenv("COLUMNS", raising=False)
    assert helptext.stored() is None


@pytest.mark.parametrize("columns", ["120", "79", "0", "x"])
def test_columns_are_found_as_shutil_finds_them(monkeypatch: pytest.MonkeyPatch,
                                                columns: str) -> None:
    """argparse wraps to shutil's width; the fast path must agree on when it may answer."""
    monkeypatch.setenv("COLUMNS", columns)
    assert helptext.columns() == shutil.get_terminal_size().columns
