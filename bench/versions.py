"""This lpam beside another checkout of it (an earlier commit), on one interpreter.

    git worktree add /tmp/lpam-before <commit>
    .venv/bin/python -m bench.versions --other /tmp/lpam-before [--reps 9]

What a refactoring costs at run time, measured rather than assumed: a no-op `lpam plan`,
`lpam status`, and a saved plan of a cold apply (one checkout step per repository) written
(`plan --out`) and read back (`validate`, which loads it as `apply PLANFILE` does before the
lock), and that cold apply itself (fetches from the daemon and checkouts, into a fresh root
each round, removed after). Each checkout runs its own code (`python -m reconciler` from
its folder) with the same libraries; each writes and reads its own plan format. One fixture
serves both (the repositories of bench/repos.py pinned to commits on a loopback git daemon,
applied once by the other, earlier checkout: a newer lpam reads its record through the
migration). The checkouts take turns within each round, every run a fresh process, and
each figure is a ratio to this checkout's in the same rounds: these machines are noisy.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.pythons import print_ratios
from bench.repos import CountingDaemon, build_repos, desired_state
from bench.run import TIMEOUT, machine, sh
from tests.gitserver import git_env

TOP = Path(__file__).resolve().parents[1]


def commit_of(folder: Path) -> str:
    done = subprocess.run(["git", "-C", str(folder), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True, timeout=TIMEOUT, check=False)
    return done.stdout.strip() or folder.name


def run_in(folder: Path, argv: list[str], env: dict[str, str]) -> float:
    """One fresh `python -m reconciler …` with `folder`'s code; its wall time."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "reconciler", *argv], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{folder}: lpam {' '.join(argv)} exited {done.returncode}:\n"
                         f"{done.stdout}{done.stderr}")
    return time.perf_counter() - started


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.versions", description=__doc__)
    parser.add_argument("--other", type=Path, required=True, help="another lpam checkout")
    parser.add_argument("--reps", type=int, default=9, help="counted rounds (default 9)")
    parser.add_argument("--repos", type=int, default=20, help="repositories (default 20)")
    parser.add_argument("--commits", type=int, default=10, help="commits each (default 10)")
    args = parser.parse_args(argv)
    if not (args.other / "reconciler" / "__main__.py").is_file():
        parser.error(f"{args.other} is no lpam checkout")
    if not 1 <= args.reps <= 100 or not 1 <= args.repos <= 200 or not 1 <= args.commits <= 1000:
        parser.error("keep --reps <= 100, --repos <= 200 and --commits <= 1000")
    folders = [TOP, args.other.resolve()]
    with tempfile.TemporaryDirectory(prefix="lpam-bench-versions-") as name:
        tmp = Path(name)
        (tmp / "home").mkdir()
        env = git_env(tmp / "home")
        for folder in folders:  # byte-compiled, as an installed package is
            sh([sys.executable, "-m", "compileall", "-q", str(folder / "reconciler"),
                str(folder / "schemas"), str(folder / "migrations")], env)
        with CountingDaemon(tmp / "served", home=tmp / "home", log=tmp / "daemon.log") as daemon:
            print(f"building {args.repos} repositories ...", file=sys.stderr)
            repos = build_repos(daemon, tmp / "work", tmp / "home", count=args.repos,
                                commits=args.commits)
            desired = tmp / "desired.yaml"
            desired.write_text(desired_state(repos, pinned=True))
            root, empty = tmp / "root", tmp / "empty"
            # applied by the earlier checkout: a newer lpam reads an older state record
            # (through its migration), never the reverse
            run_in(folders[1], ["apply", "-f", str(desired), "--root", str(root), "--yes"],
                   env)
            times = _rounds(folders, desired, root, empty, tmp, args.reps, env)
    _report(folders, times, args)
    return 0


def _rounds(folders: list[Path], desired: Path, root: Path, empty: Path, tmp: Path,
            reps: int, env: dict[str, str]) -> dict[tuple[str, Path], list[float]]:
    times: dict[tuple[str, Path], list[float]] = {}
    for rnd in range(reps + 1):
        print(f"  round {rnd}/{reps}{' (warm-up)' if rnd == 0 else ''}", file=sys.stderr)
        for number, folder in enumerate(folders):
            saved, fresh = tmp / f"cold-{number}.json", tmp / f"fresh-{number}"
            commands = {
                "lpam plan (no-op)": ["plan", "-f", str(desired), "--root", str(root),
                                      "--detailed-exitcode"],
                "lpam status": ["status", "--root", str(root)],
                "lpam plan --out (cold)": ["plan", "-f", str(desired), "--root", str(empty),
                                           "--out", str(saved)],
                "read the saved plan": ["validate", "--kind", "plan", str(saved)],
                "lpam apply (cold)": ["apply", "-f", str(desired), "--root", str(fresh),
                                      "--yes"],
            }
            for label, command in commands.items():
                took = run_in(folder, command, env)
                if rnd:
                    times.setdefault((label, folder), []).append(took)
            shutil.rmtree(fresh)
    return times


def _report(folders: list[Path], times: dict[tuple[str, Path], list[float]],
            args: argparse.Namespace) -> None:
    print(f"## Machine\n\n{machine()}\n\n{args.reps} counted rounds after one warm-up; "
          f"{args.repos} repositories of {args.commits} commits pinned to commits; Python "
          f"{sys.version.split()[0]}.\n")
    print_ratios([commit_of(f) for f in folders], list(folders),
                 list(dict.fromkeys(label for label, _ in times)), times)

if __name__ == "__main__":
    sys.exit(main())
