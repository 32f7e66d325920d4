"""An app's dependencies are prepared before the cutover, and only when something changed.

One run measures, side by side, against real pip (from a wheel folder, PIP_NO_INDEX=1),
real catkin_make, a real git daemon on 127.0.0.1 serving the app and ROS repositories
(reached through `mirrors:`, as a car reaches a laptop), and a real supervisord under a
temporary root; `apt-get` is a script on PATH that records its calls (nothing is ever
installed), `dpkg-query` is the machine's own. Every app is a scriptless `ticker` (see
bench/cutover.py) that appends a timestamp to `<root>/life.log` every 20 ms.

1. An app with a pip requirement, an apt one that is installed, and a tiny catkin workspace
   (one ROS repository, one package): the first apply (makes the environment, runs pip,
   builds), an apply that changes nothing, and an apply that changes only `app.params`.
2. A switch to another app with the same requirements and ROS repository, next to a
   switch between two apps with no dependencies at all (the yardstick); both with their
   downtime.
3. Cutover downtime (old app's last line to new app's first) of a switch whose preparation
   includes a ROS build made slow on purpose (its CMakeLists.txt runs `sleep`), against the
   same switch once the build was already made by an earlier apply of another app with the
   same ROS repository.

For each apply: its wall time (a whole `lpam apply --yes` process) and, read from the apply
log it wrote (`<root>/var/log/lpam/apply-*.log`, where a line starting `$ ` is a command
lpam ran), how many catkin_make, pip and `python -m venv` runs it made. The build's own
duration comes from a `catkin_make` on PATH that runs the real one and writes down when it
started and ended. A switch's downtime is also split, with supervisord's log, into the old
app's last tick, lpam's stop → spawn, and the new app's own start. The apps' `python3` is
/usr/bin/python3 (or their venv's), not whatever PATH finds first. Each round uses fresh
roots; the figures are medians over the rounds.

    .venv/bin/python -m bench.dependencies [--reps N] [--build-sleep SECONDS]

Progress goes to stderr, a Markdown report to stdout (docs/benchmarks.md keeps one).
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from bench.cutover import TICKER
from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from tests.catkin import write_package
from tests.contract.test_packages import recording_apt_get
from tests.gitserver import GitDaemon, RepoBuilder
from tests.wheels import write_wheel

REQUIREMENT = "lpam-bench-speedo>=1.0"
DEPS = f'[{{apt: bash}}, {{pip3: "{REQUIREMENT}"}}]'
TINY = "{owner: jmscslgroup, repo: tiny_ros, branch_or_hash: main}"
SLOW = "{owner: jmscslgroup, repo: slow_ros, branch_or_hash: main}"
TICK = "command: [python3, -u, ticker.py]\n    health: {settle_seconds: 0}"
CATALOG = f"""\
apps:
  - name: vsl            # 1 and 2: pip, apt and a tiny ROS workspace
    {TICK}
    dependencies: {DEPS}
    ros_repositories: [{TINY}]
  - name: vsl2           # 2: the same requirements and ROS repository
    {TICK}
    dependencies: {DEPS}
    ros_repositories: [{TINY}]
  - name: plain1         # 2: the yardstick, no dependencies
    {TICK}
  - name: plain2
    {TICK}
  - name: old            # 3: switched from ...
    {TICK}
  - name: new            # ... to this one, whose ROS build is slow
    {TICK}
    ros_repositories: [{SLOW}]
  - name: prep           # 3: makes the same build beforehand
    {TICK}
    ros_repositories: [{SLOW}]
"""
PYTHON = "/usr/bin/python3"  # what lpam makes the environments from, and what the apps run
APPS = ("vsl", "vsl2", "plain1", "plain2", "old", "new", "prep")

TIMED_CATKIN = """#!/usr/bin/env bash
# catkin_make, timed: appends "START END FOLDER" to the file below, exits as it did.
start=$(date +%s.%N)
{real} "$@"
code=$?
echo "$start $(date +%s.%N) $PWD" >> {times}
exit $code
"""


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


@dataclass
class Apply:
    """One `lpam apply --yes`: its wall time and the commands its apply log shows."""

    seconds: float
    catkin: int
    pip: int
    venv: int
    commands: int  # every `$ ` line; lpam writes an apply log only when it has a line
    timed_catkin: int  # catkin_make runs the timing wrapper saw, whatever the log says
    building: float  # seconds those runs took
    began: float = 0.0  # time.time() when the apply started
    down: float | None = None  # a switch's downtime, when measured
    old_ran: float | None = None  # the old app's last line, in seconds after `began`
    # a switch's downtime in three: old's last line → supervisord saw old stop → it
    # spawned new → new's first line
    phases: tuple[float, float, float] | None = None


@dataclass
class Bench:
    work: Path
    env: dict[str, str]
    mirror: str
    apps_url: str
    build_times: Path
    apt_calls: Path

    def root(self, name: str) -> Path:
        root = self.work / "roots" / name
        (root / "etc" / "lpam").mkdir(parents=True)
        return root

    def want(self, root: Path, app: str, **params: str) -> None:
        text = (f"version: 1\nrepositories: [{{url: {self.apps_url}}}]\n"
                f'mirrors: {{"https://github.com/jmscslgroup/": "{self.mirror}"}}\n'
                f"app:\n  name: {app}\n")
        if params:
            text += "  params: {" + ", ".join(f'{k}: "{v}"' for k, v in params.items()) + "}\n"
        (root / "etc" / "lpam" / "desired-state.yaml").write_text(text)

    def apply(self, root: Path) -> Apply:
        logs = root / "var" / "log" / "lpam"
        before = set(logs.glob("apply-*.log")) if logs.is_dir() else set()
        builds = len(self.build_seconds(root))
        began, started = time.time(), time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "reconciler", "--root", str(root), "apply", "--yes"],
            capture_output=True, text=True, env=self.env, cwd=root.parent, timeout=600)
        took = time.perf_counter() - started
        spans = self.build_seconds(root)[builds:]
        if done.returncode != 0:
            raise SystemExit(f"lpam apply failed in {root}:\n{done.stdout}\n{done.stderr}")
        commands = []
        for path in sorted(set(logs.glob("apply-*.log")) - before):
            commands += [shlex.split(line[2:]) for line in path.read_text().splitlines()
                         if line.startswith("$ ")]
        return Apply(
            took,
            catkin=sum(any(Path(word).name == "catkin_make" for word in argv)
                       for argv in commands),
            pip=sum(_runs_module(argv, "pip") for argv in commands),
            venv=sum(_runs_module(argv, "venv") for argv in commands),
            commands=len(commands), timed_catkin=len(spans), building=sum(spans), began=began)

    def build_seconds(self, root: Path) -> list[float]:
        """How long each catkin_make under `root` took, in order."""
        if not self.build_times.exists():
            return []
        spans = []
        for line in self.build_times.read_text().splitlines():
            start, end, folder = line.split(" ", 2)
            if Path(folder).resolve().is_relative_to(root.resolve()):
                spans.append(float(end) - float(start))
        return spans


def _runs_module(argv: list[str], module: str) -> bool:
    return any(a == "-m" and b == module for a, b in zip(argv, argv[1:]))


def applies(bench: Bench, rep: int) -> dict[str, Apply]:
    """Sections 1 and 2 on one fresh root."""
    root = bench.root(f"deps{rep}")
    try:
        out = {}
        bench.want(root, "vsl")
        out["first"] = bench.apply(root)
        out["same"] = bench.apply(root)
        bench.want(root, "vsl", MODE=f"fast{rep}")
        out["params"] = bench.apply(root)
        out["switch"] = timed_switch(bench, root, "vsl", "vsl2")
        bench.want(root, "plain1")
        bench.apply(root)
        out["plain"] = timed_switch(bench, root, "plain1", "plain2")
        return out
    finally:
        shutdown(Layout(root))


def timed_switch(bench: Bench, root: Path, old: str, new: str) -> Apply:
    """Switch from the running `old` to `new`; its downtime is the gap between `old`'s last
    line and `new`'s first line in life.log."""
    time.sleep(0.3)
    bench.want(root, new)
    done = bench.apply(root)
    time.sleep(0.3)
    lines = [line.split() for line in (root / "life.log").read_text().splitlines()]
    last_old = max(float(t) for who, t in lines if who == old)
    first_new = min(float(t) for who, t in lines if who == new)
    done.down, done.old_ran = first_new - last_old, last_old - done.began
    stopped = _supervisord_says(root, f"stopped: lpam-app-{old} ", last=True)
    spawned = _supervisord_says(root, f"spawned: 'lpam-app-{new}' ", last=False)
    if stopped is not None and spawned is not None:
        done.phases = (stopped - last_old, spawned - stopped, first_new - spawned)
    return done


def _supervisord_says(root: Path, text: str, *, last: bool) -> float | None:
    """When supervisord's log (local time, milliseconds) first or last says `text`."""
    found = [datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
             for line in Layout(root).supervisor_log.read_text().splitlines()
             if text in line]
    return (found[-1] if last else found[0]) if found else None


@dataclass
class Switch:
    apply: Apply  # its `down` is always measured
    build: float | None  # seconds of the build made by this switch, or before it


def switch(bench: Bench, name: str, prebuilt: bool) -> Switch:
    """old → new on a fresh root; with `prebuilt`, another app with the same ROS repository
    was applied first, so the build exists before the switch."""
    root = bench.root(name)
    try:
        if prebuilt:
            bench.want(root, "prep")
            bench.apply(root)
        bench.want(root, "old")
        bench.apply(root)
        done = timed_switch(bench, root, "old", "new")
        builds = bench.build_seconds(root)
        return Switch(done, builds[0] if builds else None)
    finally:
        shutdown(Layout(root))


def setup(work: Path, daemon: GitDaemon, home: Path, sleep: float) -> Bench:
    for name in ("tiny_ros", "slow_ros"):
        ros = RepoBuilder(daemon.base, f"{name}.git", work_root=work / "w", home=home)
        write_package(ros.work / name, name)
        if name == "slow_ros":
            with (ros.work / name / "CMakeLists.txt").open("a") as cmake:
                cmake.write(f"execute_process(COMMAND sleep {sleep:g})  # a slow build\n")
        ros.commit(f"the package {name}")
        ros.push()
    apps = RepoBuilder(daemon.base, "apps.git", work_root=work / "w", home=home)
    apps.write("libpanda-apps.yaml", CATALOG)
    for app in APPS:
        apps.write(f"{app}/ticker.py", TICKER)
    apps.commit("the apps")
    apps.push()

    wheels, fakebin = work / "wheels", work / "bin"
    write_wheel(wheels, "lpam-bench-speedo", "1.0", module="speedo", source="SPEED = 0\n")
    apt_calls, build_times = work / "apt-calls", work / "catkin-times"
    recording_apt_get(fakebin, apt_calls)
    real = shutil.which("catkin_make")
    if real is None:
        raise SystemExit("catkin_make is not on PATH (Debian's `catkin` package)")
    timed = fakebin / "catkin_make"
    timed.write_text(TIMED_CATKIN.format(real=shlex.quote(real),
                                         times=shlex.quote(str(build_times))))
    timed.chmod(0o755)
    # The apps' `python3` is the system's, as on a vehicle, not whatever PATH finds first
    # (a pyenv shim adds 0.2 s to every start); apps with a pip requirement get their venv's.
    (fakebin / "python3").symlink_to(PYTHON)
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("PIP_", "PYTHON", "GIT_")) and k != "XDG_CACHE_HOME"}
    env.update(PATH=f"{fakebin}{os.pathsep}{os.environ['PATH']}", HOME=str(home),
               PIP_NO_INDEX="1", PIP_FIND_LINKS=str(wheels), PIP_CONFIG_FILE=os.devnull,
               LPAM_SERVICES="supervisor")
    return Bench(work, env, daemon.url(""), daemon.url("apps.git"), build_times, apt_calls)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--build-sleep", type=float, default=3.0,
                        help="seconds the slow package's CMakeLists.txt sleeps (default: 3)")
    args = parser.parse_args(argv)
    began = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="lpam-deps-") as tmp:
        work = Path(tmp)
        home = work / "home"
        home.mkdir()
        with GitDaemon(work / "served", home=home) as daemon:
            bench = setup(work, daemon, home, args.build_sleep)
            rounds: list[dict[str, Apply]] = []
            slow: list[Switch] = []
            built: list[Switch] = []
            for rep in range(args.reps):
                log(f"  round {rep + 1}/{args.reps}: applies")
                rounds.append(applies(bench, rep))
                log(f"  round {rep + 1}/{args.reps}: switch with the build in it")
                slow.append(switch(bench, f"slow{rep}", prebuilt=False))
                log(f"  round {rep + 1}/{args.reps}: switch with the build done before")
                built.append(switch(bench, f"built{rep}", prebuilt=True))
            apt = bench.apt_calls.read_text().splitlines() if bench.apt_calls.exists() else []
    report(args, rounds, slow, built, apt, time.perf_counter() - began)
    return 0


def _med(values: Sequence[float]) -> float:
    return statistics.median(values)


def _counts(values: Sequence[int]) -> str:
    low, high = min(values), max(values)
    return str(low) if low == high else f"{low}-{high}"


def report(args: argparse.Namespace, rounds: list[dict[str, Apply]], slow: list[Switch],
           built: list[Switch], apt: list[str], total: float) -> None:
    catkin = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "catkin"],
                            capture_output=True, text=True, check=False).stdout or "?"
    print(f"### Dependencies prepared before the cutover ({args.reps} rounds, fresh roots)\n")
    print(f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}, {platform.system()} "
          f"{platform.release()}, Python {platform.python_version()} (lpam), Debian catkin "
          f"{catkin}; the whole run took {total:.0f} s.\n")
    rows = [
        ("first", "first apply: venv, pip, catkin_make, start"),
        ("same", "apply that changes nothing"),
        ("params", "apply that changes only `app.params`"),
        ("switch", "switch to an app with the same requirements and ROS repository"),
        ("plain", "switch between two apps without dependencies (yardstick)"),
    ]
    first = _med([r["first"].seconds for r in rounds])
    print("| apply | median s | min s | max s | x first apply | catkin_make runs | pip runs "
          "| venvs made | commands logged | catkin_make s (median) | downtime s (median) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for key, label in rows:
        runs = [r[key] for r in rounds]
        times = [a.seconds for a in runs]
        downs = [a.down for a in runs if a.down is not None]
        print(f"| {label} | {_med(times):.3f} | {min(times):.3f} | {max(times):.3f} | "
              f"{_med(times) / first:.2f} | {_counts([a.catkin for a in runs])} | "
              f"{_counts([a.pip for a in runs])} | {_counts([a.venv for a in runs])} | "
              f"{_counts([a.commands for a in runs])} | {_med([a.building for a in runs]):.3f} | "
              f"{f'{_med(downs):.3f}' if downs else '-'} |")
    quiet = [r[k] for r in rounds for k in ("same", "params")]
    met = all(a.catkin == 0 and a.pip == 0 and a.venv == 0 for a in quiet)
    shared = [r["switch"] for r in rounds]
    ratio = _med([a.seconds for a in shared]) / _med([r["plain"].seconds for r in rounds])
    print(f"\nNo catkin_make and no pip when nothing changed or only params did: "
          f"{'met' if met else 'NOT met'}. Switch to an app with the same requirements: "
          f"{'no pip run' if all(a.pip == 0 for a in shared) else 'pip RAN'}, "
          f"{ratio:.2f}x the time of the switch without dependencies. "
          f"apt-get calls in the whole run: {len(apt)} (`bash` is installed).")
    every = [a for r in rounds for a in r.values()] + [s.apply for s in [*slow, *built]]
    odd = sum(a.catkin != a.timed_catkin for a in every)
    print(f"catkin_make runs seen by the timing wrapper "
          f"{'agree with the apply logs' if not odd else f'DISAGREE with {odd} apply logs'}; "
          f"an apply with 0 commands logged wrote no apply log at all.\n")

    print(f"### Cutover downtime with a slow ROS build ({args.reps} switches each; the "
          f"package's CMakeLists.txt sleeps {args.build_sleep:g} s)\n")
    print("| switch old → new | apply s (median) | build s (median) | old app's last line, "
          "s into the apply (median) | downtime s (median) | downtime s (max) | catkin_make "
          "runs in the switch |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for label, switches in (("`new`'s ROS build made in the switch's preparation", slow),
                        ("build already made (by an earlier apply of another app)", built)):
        builds = [s.build for s in switches if s.build is not None]
        shown = f"{_med(builds):.3f}" if builds else "-"
        if switches is built and builds:
            shown = f"({shown}, before)"
        downs = [s.apply.down or 0.0 for s in switches]
        print(f"| {label} | {_med([s.apply.seconds for s in switches]):.3f} | {shown} | "
              f"{_med([s.apply.old_ran or 0.0 for s in switches]):.3f} | "
              f"{_med(downs):.3f} | {max(downs):.3f} | "
              f"{_counts([s.apply.catkin for s in switches])} |")
    down_slow = _med([s.apply.down or 0.0 for s in slow])
    down_built = _med([s.apply.down or 0.0 for s in built])
    build = _med([s.build for s in slow if s.build is not None] or [float("nan")])
    took = _med([s.apply.seconds for s in slow]) / _med([s.apply.seconds for s in built])
    print(f"\nDowntime ratio, build in the switch / build before: {down_slow / down_built:.2f}; "
          f"build time / downtime: {build / down_slow:.0f}x; apply time ratio: {took:.2f}\n")

    print("### Where the downtime goes (medians, s; from life.log and supervisord's log)\n")
    print("| switch | downtime | old's last line → supervisord stopped it | stopped → new "
          "spawned (lpam: uninstall, install, start) | spawned → new's first line |")
    print("|---|---:|---:|---:|---:|")
    for label, runs in (("same requirements and ROS repository", [r["switch"] for r in rounds]),
                        ("no dependencies (yardstick)", [r["plain"] for r in rounds]),
                        ("slow ROS build in the preparation", [s.apply for s in slow]),
                        ("slow ROS build made before", [s.apply for s in built])):
        phases = [a.phases for a in runs if a.phases is not None]
        cells = " | ".join(f"{_med([p[i] for p in phases]):.3f}" for i in range(3)) \
            if phases else "- | - | -"
        print(f"| {label} | {_med([a.down or 0.0 for a in runs]):.3f} | {cells} |")


if __name__ == "__main__":
    sys.exit(main())
