"""What an agent pass costs on the network: a no-op pass, and a pass after one pin moved.

A fleet of cars polls its desired-state repository every few minutes, so the pass where
nothing changed is the one paid most often. The fixture is 20 app repositories and a
desired-state repository pinning each to a full hash, behind a loopback `git daemon` that
logs every connection (bench/repos.py). Measured in one run, side by side:

- the first pass (clones everything);
- no-op passes: connections per pass, and bytes added to lpam's store (objects fetched);
- a pass after one app repository got a new commit and the desired state's pin moved to
  it: connections, and bytes added (only that repository's new objects should come);
- for scale, `git fetch` of the desired-state repository alone, run the same way.

Every pass also pushes the car's status to `status/<vehicle>` (one more connection and a
commit of about a kilobyte); the bytes column counts what the store gained, that commit
included.

    .venv/bin/python -m bench.agent [--reps N]

Progress goes to stderr, a Markdown report to stdout (docs/benchmarks.md keeps one).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from bench.repos import CountingDaemon, build_repos, desired_state
from tests.gitserver import RepoBuilder, git_env

COUNT = 20


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def store_bytes(root: Path) -> int:
    """Bytes of git objects in lpam's store (what fetching adds to)."""
    base = root / "var" / "lib" / "lpam" / "repositories"
    return sum(p.stat().st_size for p in base.rglob("*") if p.is_file() and
               "objects" in p.parts)


def run(argv: list[str], env: dict[str, str], daemon: CountingDaemon) -> tuple[float, int]:
    """(seconds, connections) of one command that must succeed."""
    before = daemon.connections()
    started = time.perf_counter()
    done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=600,
                          check=False)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed: {done.stdout}{done.stderr}")
    time.sleep(0.2)  # the daemon logs a connection as it accepts it; let the log catch up
    return seconds, daemon.connections() - before


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--reps", type=int, default=5)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="lpam-bench-agent-") as tmp_name:
        tmp = Path(tmp_name)
        home = tmp / "home"
        home.mkdir()
        served = tmp / "served"
        # The fleet repository accepts pushes: each pass publishes the car's status.
        with CountingDaemon(served, home=home, log=tmp / "daemon.log",
                            receive_pack=True) as daemon:
            log(f"building {COUNT} app repositories and the fleet's …")
            repos = build_repos(daemon, tmp / "work", home, count=COUNT, commits=5)
            fleet = RepoBuilder(served, "fleet.git", work_root=tmp / "work", home=home)
            fleet.commit("every car", {"desired-state.yaml": desired_state(repos, pinned=True)})
            fleet.push()
            root = tmp / "root"
            (root / "etc" / "lpam").mkdir(parents=True)
            (root / "etc" / "lpam" / "agent.yaml").write_text(
                f"version: 1\nsource: {{url: {daemon.url('fleet.git')}}}\nvehicle: car-01\n")
            env = dict(os.environ, HOME=str(home), LPAM_SERVICES="supervisor")
            sync = [sys.executable, "-m", "reconciler", "--root", str(root), "sync"]

            first, first_conn = run(sync, env, daemon)
            log(f"first pass: {first:.2f} s, {first_conn} connections")
            noop_times, noop_conn, noop_bytes = [], [], []
            for _ in range(args.reps):
                before = store_bytes(root)
                seconds, conns = run(sync, env, daemon)
                noop_times.append(seconds)
                noop_conn.append(conns)
                noop_bytes.append(store_bytes(root) - before)
            log(f"no-op passes: {noop_conn} connections, {noop_bytes} bytes")

            changed = RepoBuilder(served, repos[7].name, work_root=tmp / "again", home=home)
            changed.git("pull", "--quiet", "origin", "main")
            tip = changed.commit("one more change", {"app-07/data/new.txt": "new\n" * 50})
            changed.push()
            moved = [r if r.name != repos[7].name else type(r)(r.name, r.url, tip)
                     for r in repos]
            fleet.commit("move one pin", {"desired-state.yaml": desired_state(moved,
                                                                              pinned=True)})
            fleet.push()
            before = store_bytes(root)
            pin_time, pin_conn = run(sync, env, daemon)
            pin_bytes = store_bytes(root) - before
            log(f"after one pin moved: {pin_conn} connections, {pin_bytes} bytes")

            clone = tmp / "fleet-clone"
            subprocess.run(["git", "clone", "--quiet", daemon.url("fleet.git"), str(clone)],
                           env=git_env(home), check=True, capture_output=True)
            git_times, git_conn = [], []
            for _ in range(args.reps):
                seconds, conns = run(["git", "-C", str(clone), "fetch", "--quiet"],
                                     git_env(home), daemon)
                git_times.append(seconds)
                git_conn.append(conns)
            subprocess.run([sys.executable, "-m", "reconciler", "--root", str(root),
                            "services", "shutdown"], env=env, capture_output=True,
                           check=False)

    noop = statistics.median(noop_times)
    fetch = statistics.median(git_times)
    print(f"Fixture: {COUNT} app repositories pinned to full hashes by one desired-state "
          f"repository, loopback git daemon; median of {args.reps}.\n")
    print("| pass | connections | bytes added to the store | median s |")
    print("|---|---:|---:|---:|")
    print(f"| first pass (clones everything) | {first_conn} | - | {first:.3f} |")
    print(f"| no-op pass | {_span(noop_conn)} | {_span(noop_bytes)} | {noop:.3f} |")
    print(f"| one pin moved | {pin_conn} | {pin_bytes} | {pin_time:.3f} |")
    print(f"| `git fetch` of the desired-state repository alone | {_span(git_conn)} | - | "
          f"{fetch:.3f} |")
    print(f"\nNo-op pass / `git fetch` of the fleet repository: {noop / fetch:.1f}x "
          "(lpam's process start, plan and status writing included).")
    return 0


def _span(values: Sequence[int]) -> str:
    low, high = min(values), max(values)
    return str(low) if low == high else f"{low} to {high}"


if __name__ == "__main__":
    sys.exit(main())
