"""Where a `lpam plan` run spends its time, phase by phase, in one fresh interpreter.

    .venv/bin/python -m bench.phases DESIRED.yaml ROOT     # prints one JSON object

Why not cProfile: `resolve` works in a thread pool, which cProfile does not see, and a
profiler's overhead falls unevenly on import-heavy and call-heavy code. This mirrors
`reconciler.cli.cmd_plan` / `_prepare` step by step (keep it in step with them) and times
each step with a plain clock. Imports are timed in the order the CLI meets them, so each
line is what that import adds on top of the ones before it.
"""

from __future__ import annotations

import importlib
import json
import sys
import time
from pathlib import Path

IMPORTS = {  # phase name: modules, in the order `lpam plan` first imports them
    "import cli (argparse, layout, errors)": ["reconciler.cli"],
    "import render (schemas.plan: pydantic)": ["reconciler.planning.render"],
    "import documents (ruamel.yaml, schemas)": ["reconciler.documents"],
    "import adapters.git (dulwich)": ["reconciler.adapters.git"],
    "import observe (state record, journal)": ["reconciler.observe.machine",
                                               "reconciler.observe.targets"],
    "import planning.plan (networkx)": ["reconciler.planning.plan"],
}


def phases(desired_path: Path, root: Path) -> dict[str, float]:
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

    from reconciler import __version__
    from reconciler.adapters.git import GitStore
    from reconciler.cli import now
    from reconciler.documents import load_desired
    from reconciler.layout import Layout
    from reconciler.observe.machine import observe
    from reconciler.observe.targets import Fetch, resolve
    from reconciler.planning.plan import make_plan
    from reconciler.planning.render import render

    layout = Layout(root.resolve())
    desired = load_desired(desired_path)
    lap("load_desired (parse + validate YAML)")
    store = GitStore(layout, timeout=60.0)
    targets = resolve(desired, base_dir=desired_path.resolve().parent, store=store,
                      fetch=Fetch.OBJECTS)
    lap("resolve (refs -> commits, thread pool)")
    observed = observe(layout, store, targets)
    lap("observe (record, checkouts, journal)")
    plan = make_plan(targets, observed, now=now(), lpam_version=__version__)
    lap("make_plan (diff + graph)")
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
