"""lpam against vcstool and plain git on the same repositories, side by side in one run.

    .venv/bin/python -m bench.run [--reps 5] [--repos 20] [--commits 30] [--no-branch]

Why this shape: wall-clock figures on a shared 2-core machine swing by tens of percent
from one minute to the next, so every tool is run in the same round-robin (one warm-up
round, then `--reps` counted rounds) and each is reported as a ratio to the reference
tool measured in the same rounds. Each run is a fresh process, start-up included, as an
operator would see it. Connections are counted from the daemon's own log, so "no network"
is observed, not assumed. Everything lives in one temporary directory, the server listens on
127.0.0.1 only, and the daemon's process group is killed on the way out.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path

from bench.repos import CountingDaemon, Repo, build_repos, desired_state, repos_file
from tests.gitserver import git_env

TOP = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
LPAM = str(BIN / "lpam")
LIBRARIES = ("import gc; gc.disable(); from pydantic import BaseModel; import ruamel.yaml, "
             "dulwich.repo, argparse")  # gc off as in lpam (reconciler.frontends.cli.entry)
VCS = str(BIN / "vcs")
TIMEOUT = 600  # seconds; no single command of a benchmark should come near it


def sh(argv: Sequence[str], env: dict[str, str], *, ok: tuple[int, ...] = (0,),
       cwd: Path | None = None) -> str:
    """Run one command; a failure stops the benchmark (a failed run would time nothing)."""
    done = subprocess.run(
        list(argv), env=env, cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT,
        check=False,
    )
    if done.returncode not in ok:
        raise RuntimeError(f"{' '.join(argv)} exited {done.returncode}:\n{done.stderr[-2000:]}")
    return done.stdout + done.stderr


@dataclass
class Contender:
    """One tool in a comparison: `run` is timed, `prepare` (untimed) runs before each run."""

    name: str
    run: Callable[[], object]
    prepare: Callable[[], object] = lambda: None
    times: list[float] = field(default_factory=list)
    connections: list[int] = field(default_factory=list)


@dataclass
class Section:
    title: str
    contenders: list[Contender]
    reference: str  # the contender the ratios are taken against
    target: tuple[str, float] | None = None  # (contender, the target ratio)


@dataclass
class Fixture:
    tmp: Path
    env: dict[str, str]
    daemon: CountingDaemon
    repos: list[Repo]
    fresh: list[int] = field(default_factory=lambda: [0])

    def path(self, name: str) -> Path:
        return self.tmp / name

    def empty_dir(self, stem: str) -> Path:
        """A new, empty directory for a cold run (the previous one is removed)."""
        self.fresh[0] += 1
        for old in self.tmp.glob(f"{stem}-*"):
            shutil.rmtree(old)
        path = self.tmp / f"{stem}-{self.fresh[0]}"
        path.mkdir()  # vcs import wants its target to exist
        return path

    def write(self, name: str, text: str) -> Path:
        path = self.tmp / name
        path.write_text(text)
        return path


def measure(sections: list[Section], fx: Fixture, reps: int) -> None:
    """Round-robin: warm-up round 0 is not counted, then `reps` rounds of every tool."""
    for rnd in range(reps + 1):
        print(f"  round {rnd}/{reps}{' (warm-up)' if rnd == 0 else ''}", file=sys.stderr)
        for section in sections:
            for c in section.contenders:
                c.prepare()
                before = fx.daemon.connections()
                started = time.perf_counter()
                c.run()
                elapsed = time.perf_counter() - started
                if rnd:
                    c.times.append(elapsed)
                    c.connections.append(fx.daemon.connections() - before)


# -- the tools -----------------------------------------------------------------------------


def lpam(fx: Fixture, *args: str) -> Callable[[], str]:
    return lambda: sh([LPAM, *args], fx.env)


def vcs_import(fx: Fixture, repos: Path, into: Callable[[], Path]) -> Callable[[], str]:
    return lambda: sh([VCS, "import", "--workers", "2", "--input", str(repos), str(into())],
                      fx.env)


def git_clone_loop(fx: Fixture, into: Callable[[], Path], *, pinned: bool) -> Callable[[], None]:
    """Sequential `git clone` (+ `git checkout HASH` when pinned), one repository at a time."""

    def run() -> None:
        base = into()
        for repo in fx.repos:
            work = base / repo.name.removesuffix(".git")
            sh(["git", "clone", "--quiet", "--branch", "main", repo.url, str(work)], fx.env)
            if pinned:
                sh(["git", "-C", str(work), "checkout", "--quiet", "--detach", repo.tip], fx.env)

    return run


def git_fetch_loop(fx: Fixture, base: Path, *, pinned: bool) -> Callable[[], None]:
    """The no-op update a shell script would do: `git fetch` + `git checkout` per clone."""

    def run() -> None:
        for repo in fx.repos:
            work = str(base / repo.name.removesuffix(".git"))
            sh(["git", "-C", work, "fetch", "--quiet", "origin"], fx.env)
            target = repo.tip if pinned else "origin/main"
            sh(["git", "-C", work, "checkout", "--quiet", "--detach", target], fx.env)

    return run


# -- the comparisons -----------------------------------------------------------------------


def _refs(pinned: bool) -> str:
    return "pinned to full hashes" if pinned else "at ref main"


def noop(fx: Fixture, *, pinned: bool) -> Section:
    """Everything already present: plan (lpam), re-import (vcs), fetch+checkout (git)."""
    kind = "pinned" if pinned else "branch"
    desired = fx.write(f"desired-{kind}.yaml", desired_state(fx.repos, pinned=pinned))
    repos = fx.write(f"{kind}.repos", repos_file(fx.repos, pinned=pinned))
    root, ws_vcs, ws_git = (fx.path(f"noop-{kind}-{n}") for n in ("lpam", "vcs", "git"))
    sh([LPAM, "apply", "-f", str(desired), "--root", str(root), "--yes"], fx.env)
    ws_vcs.mkdir()
    sh([VCS, "import", "--workers", "2", "--input", str(repos), str(ws_vcs)], fx.env)
    git_clone_loop(fx, lambda: ws_git, pinned=pinned)()
    return Section(
        title=f"1. No-op, {len(fx.repos)} repositories {_refs(pinned)}",
        contenders=[
            Contender("lpam plan", lpam(fx, "plan", "-f", str(desired), "--root", str(root),
                                        "--detailed-exitcode")),  # exit 2 would mean changes
            Contender("vcs import", vcs_import(fx, repos, lambda: ws_vcs)),
            Contender("git fetch+checkout loop", git_fetch_loop(fx, ws_git, pinned=pinned)),
            # the floor: what importing the design card's libraries alone costs
            Contender("python: import the libraries", lambda: sh(
                [sys.executable, "-c", LIBRARIES], fx.env)),
        ],
        reference="vcs import",
        target=("lpam plan", 0.25) if pinned else None,
    )


def cold(fx: Fixture, *, pinned: bool) -> Section:
    """Nothing present: every tool clones all repositories into a fresh, empty directory."""
    kind = "pinned" if pinned else "branch"
    desired = fx.write(f"desired-{kind}.yaml", desired_state(fx.repos, pinned=pinned))
    repos = fx.write(f"{kind}.repos", repos_file(fx.repos, pinned=pinned))
    target: dict[str, Path] = {}

    def fresh(stem: str) -> Callable[[], None]:
        return lambda: target.__setitem__(stem, fx.empty_dir(f"cold-{kind}-{stem}"))

    return Section(
        title=f"2. Cold apply of {len(fx.repos)} repositories {_refs(pinned)} into an empty dir",
        contenders=[
            Contender("lpam apply",
                      lambda: sh([LPAM, "apply", "-f", str(desired), "--root",
                                  str(target["lpam"]), "--yes"], fx.env),
                      prepare=fresh("lpam")),
            Contender("vcs import", vcs_import(fx, repos, lambda: target["vcs"]),
                      prepare=fresh("vcs")),
            Contender("git clone loop", git_clone_loop(fx, lambda: target["git"], pinned=pinned),
                      prepare=fresh("git")),
        ],
        reference="vcs import",
        target=("lpam apply", 0.4) if pinned else None,
    )


def startup(fx: Fixture) -> Section:
    root = fx.path("noop-pinned-lpam")
    return Section(
        title=f"3. Start-up (status reads {len(fx.repos)} applied repositories)",
        contenders=[
            Contender("python -c pass", lambda: sh([sys.executable, "-c", "pass"], fx.env)),
            Contender("lpam --version", lpam(fx, "--version")),
            Contender("lpam status", lpam(fx, "status", "--root", str(root))),
            Contender("vcs --help", lambda: sh([VCS, "--help"], fx.env)),
        ],
        reference="python -c pass",
    )


# -- where the time goes -------------------------------------------------------------------

_IMPORT_LINE = re.compile(r"import time:\s+(\d+) \|\s+\d+ \| *(\S+)")


def import_report(fx: Fixture, *args: str) -> tuple[float, dict[str, float], set[str]]:
    """`python -X importtime -m reconciler ARGS`: (total import s, self s per top-level
    package, every module imported). Self time is summed per package because cumulative
    time is charged to whichever module happens to import a shared package first."""
    out = sh([sys.executable, "-X", "importtime", "-m", "reconciler", *args], fx.env,
             ok=(0, 2))
    by_package: dict[str, float] = {}
    modules: set[str] = set()
    for line in out.splitlines():
        match = _IMPORT_LINE.match(line)
        if match:
            modules.add(match[2])
            package = match[2].split(".")[0]
            by_package[package] = by_package.get(package, 0.0) + int(match[1]) / 1e6
    return sum(by_package.values()), by_package, modules


def phase_report(fx: Fixture, desired: Path, root: Path, reps: int) -> dict[str, list[float]]:
    """bench.phases, `reps` times in fresh interpreters: seconds per phase of `lpam plan`,
    plus what the process costs around them (interpreter start-up and, above all, exit:
    the final garbage collection over every object the imports created)."""
    runs: dict[str, list[float]] = {}
    for _ in range(reps):
        started = time.perf_counter()
        out = sh([sys.executable, "-m", "bench.phases", str(desired), str(root)], fx.env,
                 cwd=TOP)
        wall = time.perf_counter() - started
        for name, seconds in json.loads(out).items():
            runs.setdefault(name, []).append(float(seconds))
        inside = runs["total after interpreter start"][-1]
        runs.setdefault("interpreter start-up + exit (wall - total)", []).append(wall - inside)
        runs.setdefault("wall clock of the process", []).append(wall)
    return runs


# -- report --------------------------------------------------------------------------------


def table(section: Section) -> str:
    ref = next(c for c in section.contenders if c.name == section.reference)
    ref_median, ref_min = statistics.median(ref.times), min(ref.times)
    lines = [
        f"### {section.title}", "",
        f"| tool | median s | min s | x {ref.name} (median) | x {ref.name} (min) "
        "| connections per run |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for c in section.contenders:
        low, high = min(c.connections), max(c.connections)
        lines.append(
            f"| {c.name} | {statistics.median(c.times):.3f} | {min(c.times):.3f} "
            f"| {statistics.median(c.times) / ref_median:.2f} | {min(c.times) / ref_min:.2f} "
            f"| {low if low == high else f'{low}-{high}'} |"
        )
    if section.target is not None:
        name, goal = section.target
        mine = next(c for c in section.contenders if c.name == name)
        ratio = statistics.median(mine.times) / ref_median
        verdict = "met" if ratio <= goal else "NOT met"
        lines += ["", f"Target {name} <= {goal} x {ref.name}: {verdict} "
                      f"(median ratio {ratio:.2f}, min ratio {min(mine.times) / ref_min:.2f})"]
    return "\n".join(lines)


def machine() -> str:
    git = sh(["git", "--version"], dict(os.environ)).strip()
    info = [
        f"{os.cpu_count()} CPUs, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}",
        f"{platform.system()} {platform.release()} {platform.machine()}",
        f"Python {platform.python_version()}, {git}",
        f"lpam {version('lpam')}, dulwich {version('dulwich')}, vcstool {version('vcstool')}, "
        f"pydantic {version('pydantic')}, networkx {version('networkx')}",
    ]
    return "\n".join(f"- {line}" for line in info)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.run", description="lpam against vcstool and plain git"
    )
    parser.add_argument("--reps", type=int, default=5, help="counted rounds (default 5)")
    parser.add_argument("--repos", type=int, default=20, help="repositories (default 20)")
    parser.add_argument("--commits", type=int, default=30, help="commits each (default 30)")
    parser.add_argument("--no-branch", action="store_true", help="skip the `ref: main` variants")
    args = parser.parse_args(argv)
    if not 1 <= args.reps <= 100 or not 1 <= args.repos <= 200 or not 1 <= args.commits <= 1000:
        parser.error("keep --reps <= 100, --repos <= 200, --commits <= 1000")

    with tempfile.TemporaryDirectory(prefix="lpam-bench-") as name:
        tmp = Path(name)
        home = tmp / "home"
        home.mkdir()
        env = git_env(home)
        # lpam's own modules byte-compiled, as `pip install` leaves an installed package
        # (vcstool's are): an editable checkout under PYTHONDONTWRITEBYTECODE=1 would
        # otherwise recompile each edited module on every run
        sh([sys.executable, "-m", "compileall", "-q", *(str(Path(__file__).parent.parent / d)
                                                       for d in ("reconciler", "schemas"))],
           env)
        with CountingDaemon(tmp / "served", home=home, log=tmp / "daemon.log") as daemon:
            print(f"building {args.repos} repositories of {args.commits} commits ...",
                  file=sys.stderr)
            repos = build_repos(daemon, tmp / "work", home, count=args.repos,
                                commits=args.commits)
            fx = Fixture(tmp=tmp, env=env, daemon=daemon, repos=repos)
            print("setting up the no-op workspaces ...", file=sys.stderr)
            sections = [noop(fx, pinned=True)]
            if not args.no_branch:
                sections.append(noop(fx, pinned=False))
            sections.append(cold(fx, pinned=True))
            if not args.no_branch:
                sections.append(cold(fx, pinned=False))
            sections.append(startup(fx))
            measure(sections, fx, args.reps)

            root = str(fx.path("noop-pinned-lpam"))
            desired = str(fx.path("desired-pinned.yaml"))
            plan_args = ("plan", "-f", desired, "--root", root)
            imports = {
                "lpam --version": import_report(fx, "--version"),
                "lpam status": import_report(fx, "status", "--root", root),
                "lpam plan": import_report(fx, *plan_args),
            }
            phases = phase_report(fx, Path(desired), Path(root), args.reps)

    print(f"\n## Machine\n\n{machine()}\n\n{args.reps} counted rounds after one warm-up; "
          f"{args.repos} repositories of {args.commits} commits on a loopback git daemon.\n")
    for section in sections:
        print(table(section) + "\n")
    print("### Heavy imports\n")
    print("| command | dulwich | networkx | pydantic | ruamel | import time s |")
    print("|---|---|---|---|---|---:|")
    for label, (total, _, mods) in imports.items():
        flags = [("yes" if any(m == p or m.startswith(p + ".") for m in mods) else "no")
                 for p in ("dulwich", "networkx", "pydantic", "ruamel")]
        print(f"| {label} | {' | '.join(flags)} | {total:.3f} |")
    print("\n### Where a no-op `lpam plan` spends its time\n")
    print(f"Phases (`python -m bench.phases`, median of {args.reps} fresh interpreters; "
          "start-up alone is the `python -c pass` row above):\n")
    print("| phase | median s | min s |\n|---|---:|---:|")
    for name, times in phases.items():
        print(f"| {name} | {statistics.median(times):.3f} | {min(times):.3f} |")
    print("\nImport self time per top-level package (`-X importtime`, one run):\n")
    print("| package | s |\n|---|---:|")
    by_package = imports["lpam plan"][1]
    for package in sorted(by_package, key=lambda p: -by_package[p])[:12]:
        print(f"| {package} | {by_package[package]:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
