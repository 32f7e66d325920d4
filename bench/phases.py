"""Where a `lpam plan` run spends its time, phase by phase, in one fresh interpreter.

    .venv/bin/python -m bench.phases DESIRED.yaml ROOT     # prints one JSON object

Why not cProfile: `resolve` works in a thread pool, which cProfile does not see, and a
profiler's overhead falls unevenly on import-heavy and call-heavy code. It runs the plan use
case itself (reconciler.workflow.planning.prepare, what `lpam plan` runs) and times the
phases it reports, with a plain clock. Imports are timed in the order the CLI meets them, so each
line is what that import adds on top of the ones before it.
"""

from __future__ import annotations

import gc
import importlib
import json
import sys
import time
from pathlib import Path

IMPORTS = {  # phase name: modules, in the order `lpam plan` first imports them
    "import cli (argparse, layout, errors)": ["reconciler.frontends.cli"],
    "import render (schemas.plan: pydantic)": ["reconciler.core.planning.render"],
    "import documents (ruamel.yaml, schemas)": ["reconciler.core.documents"],
    "import adapters.git (dulwich)": ["reconciler.adapters.git"],
    "import observe (state record, journal)": ["reconciler.engine.observe.machine",
                                               "reconciler.engine.observe.targets"],
    "import planning.plan (networkx)": ["reconciler.core.planning.plan"],
    "import workflow (the use cases)": ["reconciler.workflow.planning"],
}


def phases(desired_path: Path, root: Path) -> dict[str, float]:
    # as `lpam` itself runs (reconciler.frontends.cli.entry): its imports then cost less
    gc.disable()
    times: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        times[name] = now - clock
        clock = now

    for name, modules in IMPORTS.items():
        for module in modules:
            importlib.import_module(module)
        lap(name)

    from reconciler.base.layout import Layout
    from reconciler.core.documents import load_desired
    from reconciler.core.planning.render import render
    from reconciler.engine.observe.targets import Fetch
    from reconciler.workflow.events import Event, Phase
    from reconciler.workflow.machine import Machine
    from reconciler.workflow.planning import prepare

    names = {"resolve": "resolve (refs -> commits, thread pool)",
             "observe": "observe (record, checkouts, journal)",
             "plan": "make_plan (diff + graph)"}

    def report(event: Event) -> None:
        if isinstance(event, Phase):
            lap(names[event.name])

    machine = Machine.at(Layout(root.resolve()))
    desired = load_desired(desired_path)
    lap("load_desired (parse + validate YAML)")
    _, plan = prepare(machine, desired_path, desired, fetch=Fetch.OBJECTS, report=report)
    render(plan)
    lap("render")
    return times


def main() -> int:
    started = time.perf_counter()
    result = phases(Path(sys.argv[1]), Path(sys.argv[2]))
    result["total after interpreter start"] = time.perf_counter() - started
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
