"""Every module that imports inside a function says why, once, in a comment line starting
`# Imported inside functions:`.

The accepted rule: no module imports another inside a function to dodge a cycle; a lazy
import for start-up time (or an optional dependency) is fine, with a comment saying so.
The acyclic contract (tests/importcontracts.py) proves that no import, lazy ones included,
dodges a cycle; this test holds that each module with lazy imports says why they are lazy,
so that a new one is written down with its reason, not left to be guessed.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("reconciler", "schemas", "migrations")
MARK = "# Imported inside functions:"


def first_lazy_import(tree: ast.Module) -> int | None:
    """The line of the first import written inside a function, or None."""
    lines = [node.lineno
             for function in ast.walk(tree)
             if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef))
             for node in ast.walk(function)
             if isinstance(node, (ast.Import, ast.ImportFrom))]
    return min(lines) if lines else None


def unexplained() -> list[str]:
    """`path:line` of each module's first lazy import, for modules that do not say why."""
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            line = first_lazy_import(ast.parse(text, filename=str(path)))
            if line is None:
                continue
            if not any(row.startswith(MARK) for row in text.splitlines()):
                found.append(f"{path.relative_to(ROOT)}:{line}")
    return found


def test_the_packages_are_there() -> None:
    for package in PACKAGES:
        assert (ROOT / package / "__init__.py").is_file(), package


def test_each_module_with_lazy_imports_says_why() -> None:
    missing = unexplained()
    assert not missing, (
        f"imports inside functions with no line starting {MARK!r} in the module "
        "(say why they are lazy: start-up time, an optional dependency; never to dodge "
        "a cycle): " + ", ".join(missing))
