"""`lpam --version` is answered before the CLI is imported, in argparse's words."""

from __future__ import annotations

import subprocess
import sys


def run(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=60).stdout


def test_version_imports_no_cli_and_says_what_argparse_says() -> None:
    fast = run("import sys; sys.argv = ['lpam', '--version']\n"
               "from reconciler.__main__ import main\n"
               "code = main()\n"
               "print(code, 'reconciler.frontends.cli' in sys.modules, 'argparse' in sys.modules)")
    said, verdict = fast.splitlines()
    assert verdict == "0 False False"
    slow = run("import sys\nfrom reconciler.frontends.cli import main\n"
               "try:\n    main(['--version'])\nexcept SystemExit as e:\n    assert e.code == 0")
    assert said == slow.strip()
