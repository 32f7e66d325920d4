"""The documentation's examples are documents lpam accepts (issue 18, item 6).

Every fenced ```yaml block of README.md and docs/*.md is read as `lpam validate` reads a
file: its kind decided from its keys, then validated by the reader its command uses. The
examples shipped beside them (desired-state.example.yaml, the example app repository) are
read the same way. A fault is reported at the README's own line.

A block that is not a whole document says so on its first line, `# fragment of <parent>`
(so far only `a desired state`): a comment, because the README's reader needs that fact as
much as the test, and the block then reads the same in the README and in the test. A
fragment is validated inside the smallest parent that holds it (`version: 1` and the
fragment's keys), never skipped: a misspelt key in a fragment fails like any other.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError
from reconciler.workflow.validation import Kind, validate

TOP = Path(__file__).resolve().parents[2]
PAGES = [TOP / "README.md", *sorted((TOP / "docs").glob("*.md"))]
FRAGMENT = re.compile(r"^# fragment of (?P<parent>[^:]+)")
PARENTS = {"a desired state": (Kind.DESIRED, "version: 1\n")}
"""What a fragment is wrapped into: the kind of the whole, and the lines that make it one."""
_OPEN = re.compile(r"^(?P<indent> *)```yaml\s*$")


@dataclass(frozen=True)
class Block:
    page: Path
    line: int  # the page's line of the block's first line
    text: str

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(TOP)}:{self.line}"


def blocks(page: Path) -> list[Block]:
    """The ```yaml blocks of a Markdown page, indentation of a list item removed."""
    found = []
    lines = page.read_text().splitlines()
    index = 0
    while index < len(lines):
        opened = _OPEN.match(lines[index])
        index += 1
        if opened is None:
            continue
        indent, start, body = opened["indent"], index + 1, []
        while index < len(lines) and lines[index].strip() != "```":
            body.append(lines[index].removeprefix(indent))
            index += 1
        index += 1
        found.append(Block(page, start, "\n".join(body) + "\n"))
    return found


ALL = [block for page in PAGES for block in blocks(page)]


def check(block: Block, tmp_path: Path) -> str:
    """Validate `block` (a fragment inside its parent); a fault at the page's line."""
    fragment = FRAGMENT.match(block.text)
    kind, prefix = None, ""
    if fragment is not None:
        parent = fragment["parent"].strip()
        assert parent in PARENTS, f"{block.where}: a fragment of {parent!r}: teach " \
            f"tests/unit/test_readme_examples.py its parent (known: {', '.join(PARENTS)})"
        kind, prefix = PARENTS[parent]
    path = tmp_path / f"{block.page.stem}-{block.line}.yaml"
    path.write_text(prefix + block.text)
    try:
        return validate(path, kind)
    except ConfigError as exc:
        fault = exc
    line = block.line + (fault.line or 1) - 1 - prefix.count("\n")
    pytest.fail(f"{block.page.relative_to(TOP)}:{line}:{fault.column or 1}: {fault.message} "
                f"(hint: {fault.hint})", pytrace=False)


@pytest.mark.parametrize("block", ALL, ids=[b.where for b in ALL])
def test_every_yaml_example_of_the_documentation_is_accepted(
    block: Block, tmp_path: Path,
) -> None:
    assert check(block, tmp_path).startswith("OK: ")


def test_the_readme_shows_each_kind_a_person_writes(tmp_path: Path) -> None:
    """The extraction finds the README's examples: a desired state, a catalog, agent
    settings, and fragments (a test that found no blocks would pass vacuously)."""
    readme = [b for b in ALL if b.page.name == "README.md"]
    said = [check(b, tmp_path) for b in readme]
    for kind in ("is a desired state", "is an app catalog", "is agent settings"):
        assert any(kind in line for line in said), kind
    assert sum(1 for b in readme if FRAGMENT.match(b.text)) >= 2


@pytest.mark.parametrize(("path", "kind"), [
    ("desired-state.example.yaml", "a desired state"),
    ("examples/example-apps/libpanda-apps.yaml", "an app catalog"),
    ("examples/example-apps", "an app repository"),
])
def test_the_shipped_examples_are_accepted(path: str, kind: str) -> None:
    assert f"is {kind}" in validate(TOP / path)
