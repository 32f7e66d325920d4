"""lpam on the cars' Python (3.9) beside newer ones: a no-op `lpam plan` and `lpam status`.

    .venv/bin/python -m bench.pythons [--reps 9] [--python .venv-3.9/bin/python ...]

Each `--python` is the interpreter of a virtualenv with lpam installed (`PYTHON=…
bash scripts/dev test` makes `.venv-3.9`); by default `.venv-3.9` (the Pi's Python, the
reference) and `.venv`. One fixture serves them all: 20 repositories pinned to commits on
a loopback git daemon, applied once, so that `plan` is a no-op (exit 0 with
`--detailed-exitcode`, checked on every run) and `status` reads a real state record. The
interpreters take turns within each round (one warm-up round, then `--reps` counted), every
run a fresh process, and each figure is given as a ratio to the first interpreter's in the
same rounds: these machines are noisy, ratios are what compares. `python -c pass` is each
interpreter's start-up floor.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.repos import CountingDaemon, build_repos, desired_state
from bench.run import TIMEOUT, machine, sh
from tests.gitserver import git_env

TOP = Path(__file__).resolve().parents[1]


def version_of(python: str) -> str:
    done = subprocess.run([python, "-c", "import platform; print(platform.python_version())"],
                          capture_output=True, text=True, timeout=TIMEOUT, check=True)
    return done.stdout.strip()


def libraries_of(python: str) -> str:
    """The versions of the heavy libraries that interpreter's virtualenv holds: they differ
    (dulwich 0.24 is the last for 3.9), and they are part of what is measured."""
    code = ("from importlib.metadata import version as v; print(', '.join(f'{n} {v(n)}' "
            "for n in ('dulwich', 'pydantic', 'networkx', 'python-can')))")
    done = subprocess.run([python, "-c", code], capture_output=True, text=True,
                          timeout=TIMEOUT, check=True)
    return done.stdout.strip()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.pythons", description=__doc__)
    parser.add_argument("--python", action="append", help="a virtualenv's interpreter")
    parser.add_argument("--reps", type=int, default=9, help="counted rounds (default 9)")
    parser.add_argument("--repos", type=int, default=20, help="repositories (default 20)")
    args = parser.parse_args(argv)
    pythons = args.python or [str(TOP / ".venv-3.9/bin/python"), str(TOP / ".venv/bin/python")]
    missing = [p for p in pythons if not Path(p).exists()]
    if missing:
        parser.error(f"no interpreter at {', '.join(missing)} (make .venv-3.9 with "
                     "PYTHON=/path/to/python3.9 bash scripts/dev test)")
    if not 1 <= args.reps <= 100 or not 1 <= args.repos <= 200:
        parser.error("keep --reps <= 100 and --repos <= 200")
    versions = [version_of(p) for p in pythons]

    with tempfile.TemporaryDirectory(prefix="lpam-bench-py-") as name:
        tmp = Path(name)
        home = tmp / "home"
        home.mkdir()
        env = git_env(home)
        for python in pythons:  # byte-compiled, as an installed package is
            sh([python, "-m", "compileall", "-q", *(str(TOP / d) for d in ("reconciler",
                                                                          "schemas"))], env)
        with CountingDaemon(tmp / "served", home=home, log=tmp / "daemon.log") as daemon:
            print(f"building {args.repos} repositories ...", file=sys.stderr)
            repos = build_repos(daemon, tmp / "work", home, count=args.repos, commits=10)
            desired = tmp / "desired.yaml"
            desired.write_text(desired_state(repos, pinned=True))
            root = tmp / "root"
            sh([pythons[0], "-m", "reconciler", "apply", "-f", str(desired), "--root",
                str(root), "--yes"], env)
            commands = {
                "lpam plan (no-op)": ["plan", "-f", str(desired), "--root", str(root),
                                      "--detailed-exitcode"],
                "lpam status": ["status", "--root", str(root)],
            }
            times: dict[tuple[str, str], list[float]] = {}
            for rnd in range(args.reps + 1):
                print(f"  round {rnd}/{args.reps}{' (warm-up)' if rnd == 0 else ''}",
                      file=sys.stderr)
                for label, argv_ in [*commands.items(), ("python -c pass", None)]:
                    for python in pythons:
                        full = [python, "-c", "pass"] if argv_ is None else \
                            [python, "-m", "reconciler", *argv_]
                        started = time.perf_counter()
                        sh(full, env)  # any exit but 0 (a plan with changes) stops the run
                        if rnd:
                            times.setdefault((label, python), []).append(
                                time.perf_counter() - started)

    print(f"## Machine\n\n{machine()}\n\n{args.reps} counted rounds after one warm-up; "
          f"{args.repos} repositories pinned to commits; {platform.machine()}.\n")
    for python, version in zip(pythons, versions):
        print(f"- Python {version}: {libraries_of(python)}")
    print()
    print_ratios([f"Python {v}" for v in versions], pythons, [*commands, "python -c pass"],
                 times)
    return 0


def print_ratios(names: list[str], columns: list[Any], labels: list[str],
                 times: dict[tuple[str, Any], list[float]]) -> None:
    """A markdown table: per label, each column's median (min) and its ratio to the first
    column's median in the same rounds."""
    header = " | ".join(f"{n} median s (min) | ratio" for n in names)
    print(f"| command | {header} |")
    print("|---|" + "---:|---:|" * len(columns))
    for label in labels:
        base = statistics.median(times[(label, columns[0])])
        cells = [f"{statistics.median(runs):.3f} ({min(runs):.3f}) | "
                 f"{statistics.median(runs) / base:.2f}"
                 for runs in (times[(label, column)] for column in columns)]
        print(f"| {label} | {' | '.join(cells)} |")


if __name__ == "__main__":
    sys.exit(main())
