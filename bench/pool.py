"""How many repositories to fetch at once: a cold apply's resolve of 20 repositories
with the fetch pool at 1, 2, 4 and 8 workers, side by side in one run.

    .venv/bin/python -m bench.pool [--reps 3] [--repos 20] [--commits 60]

Why this shape: each fetch is a child process (adapters/deadline.py) that waits on the
server and then writes a pack; the pool (engine/observe/targets.py FETCH_WORKERS) is
what overlaps those waits. Its size is a trade between the waits it hides and the CPU
and SD-card writes it adds on a Pi; on loopback the wait is small, so the figure here is
a floor on what the pool can save. Each size runs, round-robin, a fresh store under a
temporary root (`resolve` with Fetch.CHECKOUT, in this process: start-up excluded).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from bench.repos import build_repos, desired_state
from reconciler.adapters.git import GitStore
from reconciler.base.layout import Layout
from reconciler.core.documents import load_desired
from reconciler.engine.observe import targets
from tests.gitserver import GitDaemon

SIZES = (1, 2, 4, 8)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench.pool")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--repos", type=int, default=20)
    parser.add_argument("--commits", type=int, default=60)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="lpam-bench-pool-") as tmp:
        base = Path(tmp)
        home = base / "home"
        home.mkdir()
        with GitDaemon(base / "served", home=home) as daemon:
            print(f"building {args.repos} repositories of {args.commits} commits ...",
                  file=sys.stderr)
            repos = build_repos(daemon, base / "work", home, count=args.repos,
                                commits=args.commits)
            (base / "desired.yaml").write_text(desired_state(repos, pinned=True))
            desired = load_desired(base / "desired.yaml")
            times: dict[int, list[float]] = {size: [] for size in SIZES}
            for rnd in range(args.reps + 1):
                print(f"  round {rnd}/{args.reps}{' (warm-up)' if rnd == 0 else ''}",
                      file=sys.stderr)
                for size in SIZES:
                    root = base / f"root-{rnd}-{size}"
                    targets.FETCH_WORKERS = size
                    store = GitStore(Layout(root), timeout=60.0)
                    started = time.perf_counter()
                    targets.resolve(desired, base_dir=base, store=store,
                                    fetch=targets.Fetch.CHECKOUT, root=root)
                    if rnd:
                        times[size].append(time.perf_counter() - started)
    reference = statistics.median(times[SIZES[0]])
    print(f"\n{args.reps} rounds after a warm-up; {args.repos} repositories pinned, fetched "
          "one commit deep from a loopback git daemon into a fresh store.\n")
    print("| fetch pool | median s | min s | x 1 worker |\n|---:|---:|---:|---:|")
    for size in SIZES:
        median = statistics.median(times[size])
        print(f"| {size} | {median:.3f} | {min(times[size]):.3f} | {median / reference:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
