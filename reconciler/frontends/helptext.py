"""`lpam --help`, answered from the text argparse prints, written beforehand to help.txt.

Building the CLI's parser means importing the CLI (its console, its layout) and argparse
and declaring two dozen commands: about four times the interpreter's own start, paid by a
user who only asked what lpam can do, on a Pi several times over (issue 32). So the
top-level help is argparse's own text, rendered at 80 columns and kept in help.txt beside
this module; a test holds it equal to what the parser says, and
`python -m reconciler.frontends.helptext` writes it again after a change to the commands.

A terminal at least 80 columns wide (or no terminal: a pipe, a file) gets that text, as
git's help stays 80 columns wide on a wider screen; a narrower one gets argparse's,
wrapped to fit. This module imports nothing but `os` and `sys` until it is asked to
render: it runs before lpam's other modules are imported.
"""

from __future__ import annotations

import os
import sys

# Imported inside functions: the CLI is what `lpam --help` must not import (start-up;
# tests/unit/test_help_fast.py).

WIDTH = 80
FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "help.txt")


def columns() -> int:
    """The width argparse would wrap to, found as `shutil.get_terminal_size` finds it
    (COLUMNS, then the terminal on standard output, else 80), without importing shutil."""
    try:
        given = int(os.environ.get("COLUMNS", "0"))
    except ValueError:
        given = 0
    if given > 0:
        return given
    out = sys.__stdout__
    if out is None:
        return WIDTH
    try:
        found = os.get_terminal_size(out.fileno()).columns
    except (AttributeError, ValueError, OSError):
        return WIDTH
    return found if found > 0 else WIDTH


def stored() -> str | None:
    """The top-level help from help.txt, or None where argparse must say it: a terminal
    narrower than the text, or no help.txt (a copy of lpam without its package data)."""
    if columns() < WIDTH:
        return None
    try:
        with open(FILE, encoding="utf-8") as text:
            return text.read()
    except OSError:
        return None


def rendered() -> str:
    """What argparse prints for `lpam --help` at WIDTH columns, in the headings of the
    newest Python (3.9's argparse says "optional arguments:" where 3.10 and later say
    "options:"): the text help.txt must hold."""
    # imported here, not above: the CLI is what `lpam --help` must not import (start-up)
    from reconciler.frontends.cli import parser

    before = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(WIDTH)
    try:
        text = parser().format_help()
    finally:
        if before is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = before
    return text.replace("\noptional arguments:\n", "\noptions:\n")


def main() -> int:
    """Write help.txt from the CLI's parser."""
    with open(FILE, "w", encoding="utf-8") as out:
        out.write(rendered())
    print(f"wrote {FILE}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
