"""Start-up per command: wall and CPU time of lpam's cheap commands, beside Python and vcs.

    .venv/bin/python -m bench.startup [--reps 10] [--repos 20] [--commits 10] [--json]

Why this shape: an operator types `lpam status` or `lpam --help` and waits for the process,
so what counts is the whole process, interpreter start-up and imports included; on a Pi
that is mostly CPU, which the wall clock of a 2-core machine hides, so both are reported.
CPU is user+sys of the child and everything it waited for (`RUSAGE_CHILDREN` before and
after each run; a helper left to exit on its own, as lpam's network forkserver, would not
count, but only apply and sync start that one). The commands take turns in one round-robin
(a warm-up round, then `--reps` counted ones) and are read as ratios: `--version` and
`--help` to `python -c pass` (the same interpreter doing nothing: the floor), `status` to
`vcs status` of the same repositories. Two rows are floors, not commands: importing
pydantic's BaseModel, and the models `status` reads and renders (schemas/report.py).
`lpam status` and a no-op `lpam plan` (with `--detailed-exitcode`: any change stops the run)
read a root where a desired state pinning `--repos` repositories was applied; `vcs status`
reads a `vcs import` of the same `.repos` set. Both are set up untimed (bench/repos.py),
from a loopback `git daemon` whose process group is killed on the way out; everything
lives in one temporary directory. Each lpam command is run once more under
`python -X importtime -m reconciler` to tell which heavy libraries it imports.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from bench.repos import build_repos, desired_state, repos_file
from bench.wire import find_vcs
from tests.gitserver import GitDaemon, git_env

TOP = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
LPAM = str(BIN / "lpam")
HEAVY = ("dulwich", "networkx", "pydantic", "ruamel")
PYTHON, VCS_STATUS = "python -c pass", "vcs status"
TIMEOUT = 600
_IMPORT_LINE = re.compile(r"import time:\s+\d+ \|\s+\d+ \| *(\S+)")


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def sh(argv: Sequence[str], env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """Run one command; a failure stops the benchmark (a failed run would time nothing)."""
    done = subprocess.run(list(argv), env=env, capture_output=True, text=True,
                          timeout=TIMEOUT, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {done.returncode}:\n"
                           f"{done.stdout[-1000:]}{done.stderr[-2000:]}")
    return done


def cpu_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


@dataclass
class Command:
    name: str
    argv: list[str]
    lpam_args: list[str] | None = None  # for the import check; None: not lpam
    wall: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    imports: dict[str, bool] = field(default_factory=dict)


def commands(root: Path, desired: Path, checkout: Path, vcs: str) -> list[Command]:
    status = ["--root", str(root), "status"]
    plan = ["--root", str(root), "plan", "-f", str(desired), "--detailed-exitcode"]
    return [
        Command(PYTHON, [sys.executable, "-c", "pass"]),
        Command("lpam --version", [LPAM, "--version"], ["--version"]),
        Command("lpam --help", [LPAM, "--help"], ["--help"]),
        Command("lpam status", [LPAM, *status], status),
        Command("lpam plan (no-op)", [LPAM, *plan], plan),
        Command(VCS_STATUS, [vcs, "status", str(checkout)]),
        # floors: what `status` cannot do without, since its record and report are
        # pydantic models (the design's choice of library)
        Command("python: from pydantic import BaseModel",
                [sys.executable, "-c", "from pydantic import BaseModel"]),
        Command("python: import the report's models", [sys.executable, "-c",
                                                       "import schemas.report"]),
    ]


def measure(cmds: list[Command], env: dict[str, str], reps: int) -> None:
    """Round-robin: round 0 warms up and is not counted, then `reps` rounds of every one."""
    for rnd in range(reps + 1):
        log(f"  round {rnd}/{reps}{' (warm-up)' if rnd == 0 else ''}")
        for c in cmds:
            cpu = cpu_children()
            started = time.perf_counter()
            sh(c.argv, env)
            wall = time.perf_counter() - started
            if rnd:
                c.wall.append(wall)
                c.cpu.append(cpu_children() - cpu)


def heavy_imports(args: list[str], env: dict[str, str]) -> dict[str, bool]:
    """Which of HEAVY `python -X importtime -m reconciler ARGS` imports (its own stderr)."""
    done = sh([sys.executable, "-X", "importtime", "-m", "reconciler", *args], env)
    modules = {m[1] for m in map(_IMPORT_LINE.match, done.stderr.splitlines()) if m}
    return {p: any(m == p or m.startswith(p + ".") for m in modules) for p in HEAVY}


def median(values: Sequence[float]) -> float:
    return float(statistics.median(values))


def table(cmds: list[Command]) -> str:
    by = {c.name: c for c in cmds}
    py, vcs = by[PYTHON], by[VCS_STATUS]
    lines = [
        f"| command | median wall s | min wall s | median CPU s | x {PYTHON} (wall) "
        f"| x {PYTHON} (CPU) | x {VCS_STATUS} (wall) | x {VCS_STATUS} (CPU) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in cmds:
        wall, cpu = median(c.wall), median(c.cpu)
        lines.append(
            f"| {c.name} | {wall:.3f} | {min(c.wall):.3f} | {cpu:.3f} "
            f"| {wall / median(py.wall):.2f} | {cpu / median(py.cpu):.2f} "
            f"| {wall / median(vcs.wall):.2f} | {cpu / median(vcs.cpu):.2f} |")
    lines += ["", f"| command | {' | '.join(HEAVY)} |", f"|---|{'---|' * len(HEAVY)}"]
    for c in cmds:
        if c.lpam_args is not None:
            flags = ("yes" if c.imports[p] else "no" for p in HEAVY)
            lines.append(f"| {c.name} | {' | '.join(flags)} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.startup",
                                     description="start-up per command: lpam, python, vcs")
    parser.add_argument("--reps", type=int, default=10, help="counted rounds (default 10)")
    parser.add_argument("--repos", type=int, default=20, help="repositories (default 20)")
    parser.add_argument("--commits", type=int, default=10, help="commits each (default 10)")
    parser.add_argument("--json", action="store_true", help="JSON instead of Markdown")
    args = parser.parse_args(argv)
    if not 1 <= args.reps <= 200 or not 1 <= args.repos <= 200 or not 1 <= args.commits <= 1000:
        parser.error("keep --reps <= 200, --repos <= 200, --commits <= 1000")

    with tempfile.TemporaryDirectory(prefix="lpam-bench-startup-") as name:
        tmp = Path(name)
        home = tmp / "home"
        home.mkdir()
        env = git_env(home)
        env["PYTHONPATH"] = str(TOP)  # lpam runs this checkout's code
        # byte-compiled as `pip install` leaves lpam (and vcstool), as bench/run.py does
        sh([sys.executable, "-m", "compileall", "-q", str(TOP / "reconciler"),
            str(TOP / "schemas")], env)
        vcs = find_vcs()
        with GitDaemon(tmp / "served", home=home) as daemon:
            log(f"building {args.repos} repositories of {args.commits} commits ...")
            repos = build_repos(daemon, tmp / "work", home, count=args.repos,
                                commits=args.commits)
            desired = tmp / "desired.yaml"
            desired.write_text(desired_state(repos, pinned=True))
            listing = tmp / "pinned.repos"
            listing.write_text(repos_file(repos, pinned=True))
            root, checkout = tmp / "root", tmp / "vcs"
            checkout.mkdir()
            log("applying the desired state and importing the .repos file (untimed) ...")
            sh([LPAM, "apply", "-f", str(desired), "--root", str(root), "--yes"], env)
            sh([vcs, "import", "--input", str(listing), str(checkout)], env)
            cmds = commands(root, desired, checkout, vcs)
            measure(cmds, env, args.reps)
            for c in cmds:
                if c.lpam_args is not None:
                    c.imports = heavy_imports(c.lpam_args, env)

    if args.json:
        print(json.dumps({"reps": args.reps, "repos": args.repos, "vcs": vcs,
                          "python": sys.version.split()[0], "cpus": os.cpu_count(),
                          "commands": {c.name: {"wall": c.wall, "cpu": c.cpu,
                                                "imports": c.imports} for c in cmds}},
                         indent=2))
        return 0
    print(f"\n{args.reps} counted rounds after one warm-up, Python {sys.version.split()[0]}, "
          f"{os.cpu_count()} CPUs; status and plan read {args.repos} applied repositories. "
          f"CPU is user+sys of the process and its children. vcs is {vcs}.\n")
    print(table(cmds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
