"""Cutover downtime under supervisord, and `lpam status` with live state.

Downtime is what the vehicle feels: from the old app's last sign of life to the new app's
first. Both apps are scriptless `ticker`s that append a timestamp to one file every 20 ms,
run by a real supervisord under a temporary root; lpam switches from one to the other.
The switch is measured twice in the same run, side by side: once with a small
preparation, once while the same apply also fetches a large repository (LARGE_MB of
incompressible blobs). The claim is that preparation happens while the old app still
runs, so the second downtime is no larger than the first: the ratio is the figure.

`lpam status` is timed three ways in one run: with the installed app's unit asked of
supervisord (live state); with `--services systemd` pointed at a fake `systemctl` that
answers at once (the cost of the backend itself set aside); and lpam as it was before
live state (`--baseline REV`, run from a `git worktree` of that commit), on a root of
its own with the same repository and a script app (the old lpam knows no scriptless
apps). The issue's bound is the first against the last: at most 1.5x.

    .venv/bin/python -m bench.cutover [--reps N] [--large-mb N] [--baseline REV]

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

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from tests.gitserver import GitDaemon, RepoBuilder

TICKER = """\
import os, time
out = os.path.join(os.environ["LPAM_ROOT"], "life.log")
me = os.environ["LPAM_APP"]
while True:
    with open(out, "a") as f:
        f.write(f"{me} {time.time():.4f}\\n")
    time.sleep(0.02)
"""
CATALOG = """\
apps:
  - name: old
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0}
  - name: new
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0}
"""
FAKE_SYSTEMCTL = """#!/bin/sh
echo "LoadState=loaded"; echo "ActiveState=active"; echo "SubState=running"
echo "NRestarts=0"; echo "MainPID=1"
"""


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


TOP = Path(__file__).resolve().parents[1]
SITE = next(p for p in sys.path if p.endswith("site-packages"))


def lpam(root: Path, *args: str, env: dict[str, str] | None = None,
         code: Path = TOP) -> float:
    """Time one whole lpam process, its code taken from the checkout `code`. It runs with
    `-S` and an explicit PYTHONPATH, because the editable install's import hook would
    otherwise load this checkout's code whatever PYTHONPATH says; the current lpam and
    the baseline start the same way, from a folder that holds no lpam."""
    env = dict(env if env is not None else os.environ, PYTHONPATH=f"{code}:{SITE}")
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-S", "-m", "reconciler", "--root", str(root), *args],
        capture_output=True, text=True, env=env, cwd=root.parent)  # `-m` puts cwd first
    if done.returncode != 0:
        raise SystemExit(f"lpam {' '.join(args)} failed: {done.stderr}")
    return time.perf_counter() - started


def desired(url: str, app: str, large: str | None) -> str:
    text = f"version: 1\nrepositories:\n  - url: {url}\n    name: apps\n"
    if large is not None:
        text += f"  - url: {large}\n    name: large\n"
    return text + f"app: {app}\n"


def downtime(root: Path) -> float:
    """Seconds between old's last line and new's first line in life.log."""
    lines = [line.split() for line in (root / "life.log").read_text().splitlines()]
    last_old = max(float(t) for who, t in lines if who == "old")
    first_new = min(float(t) for who, t in lines if who == "new")
    return first_new - last_old


def switch(work: Path, name: str, url: str, large: str | None) -> tuple[float, float]:
    """One root: install old, then switch to new (fetching `large` in the same apply);
    returns (downtime, apply seconds)."""
    root = work / name
    state = root / "etc" / "lpam" / "desired-state.yaml"
    state.parent.mkdir(parents=True)
    try:
        state.write_text(desired(url, "old", None))
        lpam(root, "apply", "--yes")
        time.sleep(0.3)
        state.write_text(desired(url, "new", large))
        took = lpam(root, "apply", "--yes")
        time.sleep(0.3)
        return downtime(root), took
    finally:
        shutdown(Layout(root))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--large-mb", type=int, default=40)
    parser.add_argument("--baseline", default="b23975c",
                        help="the lpam commit before live state (default: b23975c)")
    args = parser.parse_args(argv)
    os.environ["LPAM_SERVICES"] = "supervisor"
    with tempfile.TemporaryDirectory(prefix="lpam-cut-") as tmp:
        work = Path(tmp)
        home = work / "home"
        home.mkdir()
        with GitDaemon(work / "served", home=home) as daemon:
            apps = RepoBuilder(daemon.base, "apps.git", work_root=work / "w", home=home)
            apps.write("libpanda-apps.yaml", CATALOG)
            for app in ("old", "new"):
                apps.write(f"{app}/ticker.py", TICKER)
            apps.commit("old and new")
            apps.push()
            legacy = RepoBuilder(daemon.base, "scripted.git", work_root=work / "w", home=home)
            legacy.write("libpanda-apps.yaml", "apps:\n  - name: old\n")
            legacy.write("old/start.sh", "true\n")
            legacy.write("old/service", "lpam-app-old\n")
            legacy.commit("a script app")
            legacy.push()
            log(f"building a {args.large_mb} MB repository ...")
            big = RepoBuilder(daemon.base, "large.git", work_root=work / "w", home=home)
            for n in range(args.large_mb):
                big.write(f"blob{n}.bin", os.urandom(1 << 20).hex()[: 1 << 20])
            big.write("libpanda-apps.yaml", "apps: []\n")
            big.commit("large")
            big.push()
            small_runs, large_runs = [], []
            for rep in range(args.reps):
                log(f"  round {rep + 1}/{args.reps}")
                small_runs.append(switch(work, f"s{rep}", daemon.url("apps.git"), None))
                large_runs.append(switch(work, f"l{rep}", daemon.url("apps.git"),
                                         daemon.url("large.git")))
            status_live, status_fake = status_times(work, daemon.url("apps.git"), args.reps)
            status_old = baseline_status(work, daemon.url("scripted.git"), args)
    report(args, small_runs, large_runs, status_live, status_fake, status_old)
    return 0


def status_times(work: Path, url: str, reps: int) -> tuple[list[float], list[float]]:
    root = work / "status"
    state = root / "etc" / "lpam" / "desired-state.yaml"
    state.parent.mkdir(parents=True)
    state.write_text(desired(url, "old", None))
    fake = work / "fakebin"
    fake.mkdir()
    (fake / "systemctl").write_text(FAKE_SYSTEMCTL)
    (fake / "systemctl").chmod(0o755)
    env = dict(os.environ, PATH=f"{fake}:{os.environ['PATH']}")
    live, other = [], []
    try:
        lpam(root, "apply", "--yes")
        for _ in range(reps + 1):  # the first of each is a warm-up
            live.append(lpam(root, "status"))
            other.append(lpam(root, "status", "--services", "systemd", env=env))
    finally:
        shutdown(Layout(root))
    return live[1:], other[1:]


def baseline_status(work: Path, url: str, args: argparse.Namespace) -> list[float]:
    """`lpam status` of the commit before live state, on its own root."""
    tree = work / "baseline"
    subprocess.run(["git", "-C", str(TOP), "worktree", "add", "--detach", str(tree),
                    args.baseline], check=True, capture_output=True)
    try:
        root = work / "baseline-root"
        state = root / "etc" / "lpam" / "desired-state.yaml"
        state.parent.mkdir(parents=True)
        state.write_text(desired(url, "old", None))
        lpam(root, "apply", "--yes", code=tree)
        record = (root / "var/lib/lpam/state.json").read_text()
        if '"version": 2' not in record:  # proof that the old code ran
            raise SystemExit("the baseline did not run the old lpam")
        times = [lpam(root, "status", code=tree) for _ in range(args.reps + 1)]
        return times[1:]
    finally:
        subprocess.run(["git", "-C", str(TOP), "worktree", "remove", "--force", str(tree)],
                       check=True, capture_output=True)


def report(args: argparse.Namespace, small: list[tuple[float, float]],
           large: list[tuple[float, float]], live: list[float], other: list[float],
           old: list[float]) -> None:
    def med(values: list[float]) -> float:
        return statistics.median(values)

    down_s, down_l = med([d for d, _ in small]), med([d for d, _ in large])
    took_s, took_l = med([t for _, t in small]), med([t for _, t in large])
    print(f"### Cutover downtime under supervisord ({args.reps} switches each, "
          f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f})\n")
    print("| switch | apply s (median) | downtime s (median) | downtime s (max) |")
    print("|---|---:|---:|---:|")
    print(f"| small preparation | {took_s:.3f} | {down_s:.3f} | "
          f"{max(d for d, _ in small):.3f} |")
    print(f"| + fetch of a {args.large_mb} MB repository | {took_l:.3f} | {down_l:.3f} | "
          f"{max(d for d, _ in large):.3f} |")
    print(f"\nApply time ratio large/small: {took_l / took_s:.2f}; downtime ratio "
          f"large/small: {down_l / down_s:.2f}\n")
    print("### `lpam status` with live state\n")
    print("| status | median s | min s |")
    print("|---|---:|---:|")
    print(f"| asks supervisord over its socket | {med(live):.3f} | {min(live):.3f} |")
    print(f"| asks a `systemctl` that answers at once | {med(other):.3f} | {min(other):.3f} |")
    print(f"| lpam {args.baseline} (before live state) | {med(old):.3f} | {min(old):.3f} |")
    print(f"\nLive (supervisord) against before: {med(live) / med(old):.2f}x (median), "
          f"{min(live) / min(old):.2f}x (min); the issue's bound is 1.5x.")


if __name__ == "__main__":
    sys.exit(main())
