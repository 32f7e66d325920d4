"""An import-linter contract that no import cycle exists anywhere in the listed packages.

import-linter's own `acyclic_siblings` needs 2.6 or newer, which the cars' Python 3.9
does not get (2.5.2); this contract works on both. It looks at every import lpam's
modules make — at the top or inside a function (a lazy import for start-up time is an
import all the same: it cannot dodge a cycle) — and reports each strongly connected
group of modules as a cycle, with one path through it. `.importlinter` names it
(`contract_types`) and `lint-imports`, run by the test command, checks it.
"""

from __future__ import annotations

from typing import Any

from grimp import ImportGraph
from importlinter.application import output
from importlinter.domain import fields
from importlinter.domain.contract import Contract, ContractCheck


class AcyclicContract(Contract):
    """No module of `containers` imports, through any chain, a module that imports it."""

    containers = fields.ListField(subfield=fields.StringField())

    def check(self, graph: ImportGraph, verbose: bool) -> ContractCheck:
        roots = [str(c) for c in self.contract_options["containers"]]
        modules = sorted(m for m in graph.modules
                         if any(m == r or m.startswith(r + ".") for r in roots))
        inside = set(modules)
        edges = {m: sorted(graph.find_modules_directly_imported_by(m) & inside)
                 for m in modules}
        cycles = [_path(group, edges) for group in _groups(modules, edges)]
        return ContractCheck(kept=not cycles, metadata={"cycles": cycles})

    def render_broken_contract(self, check: ContractCheck) -> None:
        for cycle in check.metadata["cycles"]:
            output.print_error(" -> ".join(cycle))
            output.new_line()


def _groups(modules: list[str], edges: dict[str, list[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan's, without recursion:
    the graph has hundreds of modules)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in modules:
        if start in index:
            continue
        work: list[tuple[str, int]] = [(start, 0)]
        while work:
            node, at = work.pop()
            if at == 0:
                index[node] = low[node] = len(index)
                stack.append(node)
                on_stack.add(node)
            followed = edges[node]
            if at < len(followed):
                work.append((node, at + 1))
                nxt = followed[at]
                if nxt not in index:
                    work.append((nxt, 0))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            if low[node] == index[node]:
                group = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    group.append(top)
                    if top == node:
                        break
                if len(group) > 1:
                    found.append(sorted(group))
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
    return found


def _path(group: list[str], edges: dict[str, list[str]]) -> list[str]:
    """One cycle through the group's first module, as a list of modules (first repeated)."""
    members = set(group)
    start = group[0]
    previous: dict[str, Any] = {start: None}
    queue = [start]
    while queue:
        node = queue.pop(0)
        for nxt in edges[node]:
            if nxt == start:
                path = [node]
                while previous[path[-1]] is not None:
                    path.append(previous[path[-1]])
                return [*reversed(path), start]
            if nxt in members and nxt not in previous:
                previous[nxt] = node
                queue.append(nxt)
    return [*group, group[0]]
