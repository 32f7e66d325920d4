"""Bytes on the wire: what lpam downloads for one pinned repository, beside plain git and vcs.

    .venv/bin/python -m bench.wire [--reps 3] [--commits 300] [--files 20] [--json]

Why this shape: a car on a metered link pays for bytes, not seconds, and a pinned
repository only needs one tree. So the fixture is one repository whose history is much
bigger than any of its trees: `--commits` commits, each rewriting one of `--files` files
with about 2 KB of random base64 (which does not delta or compress away). It is served by a
real `git daemon` on 127.0.0.1, and every tool reaches it through a counting TCP relay
(bench/relay.py), so bytes are observed on the socket, whatever the tool speaks; the
relay knows nothing of lpam. Two scenarios, each tool from the same clean state every time:

1. cold: the tip pinned, nothing present. `git clone --depth 1` (the reference: one tree),
   `git clone` (the whole history), `vcs import` of a `.repos` file pinning the tip, and
   `lpam apply` of a desired state pinning the tip's full hash (no app) on an empty root;
2. pin moved one commit ahead: the first pin is the tip's parent, the new pin the tip.
   `git fetch --depth 1 origin TIP` into a depth-1 clone of the parent (the reference),
   the same fetch without `--depth` into a full clone of the parent (for scale), and
   `lpam apply` re-pinned to the tip on the root of an apply pinned to the parent. What
   reaching the first pin cost is counted apart (a tool may fetch the tip in advance).

The served repository allows reachable commits to be asked for by hash
(`uploadpack.allowReachableSHA1InWant`, as GitHub does), for every tool alike. Tools take
turns in one round-robin (a warm-up round, then `--reps` counted ones); the report gives
median bytes each way, connections, seconds, and lpam's bytes as a ratio to its
scenario's reference. Everything lives in one temporary directory, the daemon's process
group is killed on the way out and the relay (threads in this process) is closed.
"""

from __future__ import annotations

import argparse
import base64
import json
import random
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from bench.relay import Relay, Traffic
from bench.repos import Repo, desired_state, repos_file
from tests.gitserver import GitDaemon, RepoBuilder, git_env

TOP = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
LPAM = str(BIN / "lpam")
TIMEOUT = 600


def find_vcs() -> str:
    """This virtualenv's `vcs`, or, when it cannot start, a sibling virtualenv's (vcstool
    0.3.0 imports pkg_resources, which setuptools dropped in release 81)."""
    candidates = [BIN / "vcs", *sorted(BIN.parent.parent.glob(".venv*/bin/vcs"))]
    for path in candidates:
        done = subprocess.run([str(path), "--version"], capture_output=True, check=False,
                              timeout=60) if path.exists() else None
        if done is not None and done.returncode == 0:
            return str(path)
    raise RuntimeError(f"no working vcs (vcstool) among {', '.join(map(str, candidates))}")


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def sh(argv: Sequence[str], env: dict[str, str]) -> None:
    """Run one command; a failure stops the benchmark (a failed run would count nothing)."""
    done = subprocess.run(list(argv), env=env, capture_output=True, text=True,
                          timeout=TIMEOUT, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {done.returncode}:\n{done.stderr[-2000:]}")


@dataclass
class Contender:
    name: str
    run: Callable[[], None]
    prepare: Callable[[], None] = lambda: None  # untimed, its bytes counted apart
    traffic: list[Traffic] = field(default_factory=list)
    prepared: list[Traffic] = field(default_factory=list)  # what `prepare` itself fetched
    seconds: list[float] = field(default_factory=list)


@dataclass
class Scenario:
    key: str  # its name in --json
    title: str
    contenders: list[Contender]
    reference: str
    mine: str  # lpam's row, whose ratio to the reference is the headline


def build(served: Path, work: Path, home: Path, *, commits: int, files: int) -> list[str]:
    """`served/wire.git`: `commits` commits, each rewriting one file with ~2 KB of random
    base64; returns the commits' full hashes, oldest first."""
    rng = random.Random(32)
    builder = RepoBuilder(served, "wire.git", work_root=work, home=home)
    hashes = []
    for number in range(commits):
        text = base64.encodebytes(rng.getrandbits(1536 * 8).to_bytes(1536, "little")).decode()
        hashes.append(builder.commit(f"change {number}", {f"data/{number % files:02d}.txt": text}))
    builder.push()
    builder.git("--git-dir", str(builder.bare), "config", "uploadpack.allowReachableSHA1InWant",
                "true")
    return hashes


class Fixture:
    def __init__(self, tmp: Path, env: dict[str, str], relay: Relay) -> None:
        self.tmp, self.env, self.relay = tmp, env, relay
        self.url = relay.url("wire.git")
        self.serial = 0
        self.dirs: dict[str, Path] = {}
        self.vcs = find_vcs()

    def fresh(self, stem: str) -> Path:
        """A new empty directory for `stem` (the previous one is removed)."""
        self.serial += 1
        old = self.dirs.get(stem)
        if old is not None:
            shutil.rmtree(old)
        path = self.dirs[stem] = self.tmp / f"{stem}-{self.serial}"
        path.mkdir()
        return path

    def write(self, name: str, text: str) -> Path:
        path = self.tmp / name
        path.write_text(text)
        return path

    def desired(self, tip: str) -> Path:
        return self.write(f"desired-{tip[:12]}.yaml",
                          desired_state([Repo("wire.git", self.url, tip)], pinned=True))


def scenarios(fx: Fixture, hashes: list[str]) -> list[Scenario]:
    tip, parent = hashes[-1], hashes[-2]
    dirs = fx.dirs
    vcs = fx.vcs
    repos = fx.write("wire.repos", repos_file([Repo("wire.git", fx.url, tip)], pinned=True))
    at_tip, at_parent = fx.desired(tip), fx.desired(parent)

    def git(*args: str) -> None:
        sh(["git", *args], fx.env)

    def lpam_apply(desired: Path, stem: str) -> None:
        sh([LPAM, "apply", "-f", str(desired), "--root", str(dirs[stem]), "--yes"], fx.env)

    def clone_of_parent(stem: str, *depth: str) -> Callable[[], None]:
        def prepare() -> None:
            work = str(fx.fresh(stem))
            git("-C", work, "init", "--quiet")
            git("-C", work, "remote", "add", "origin", fx.url)
            git("-C", work, "fetch", "--quiet", *depth, "origin", parent)
            # as a clone made while main was at the parent: a ref on it, which fetch
            # offers the server as "have" (HEAD alone is not offered)
            git("-C", work, "update-ref", "refs/remotes/origin/main", parent)
            git("-C", work, "checkout", "--quiet", "--detach", parent)
        return prepare

    def fetch_tip(stem: str, *depth: str) -> Callable[[], None]:
        def run() -> None:
            work = str(dirs[stem])
            git("-C", work, "fetch", "--quiet", *depth, "origin", tip)
            git("-C", work, "checkout", "--quiet", "--detach", tip)
        return run

    def fresh(stem: str) -> Callable[[], None]:
        def prepare() -> None:
            fx.fresh(stem)
        return prepare

    def lpam_at_parent() -> None:
        fx.fresh("lpam-moved")
        lpam_apply(at_parent, "lpam-moved")

    cold = Scenario(
        key="cold",
        title=f"Cold: one repository pinned to its tip ({len(hashes)} commits of history)",
        contenders=[
            Contender("git clone --depth 1",
                      lambda: git("clone", "--quiet", "--depth", "1", fx.url,
                                  str(dirs["depth1"] / "w")),
                      prepare=fresh("depth1")),
            Contender("git clone",
                      lambda: git("clone", "--quiet", fx.url, str(dirs["full"] / "w")),
                      prepare=fresh("full")),
            Contender("vcs import",
                      lambda: sh([vcs, "import", "--input", str(repos), str(dirs["vcs"])],
                                 fx.env),
                      prepare=fresh("vcs")),
            Contender("lpam apply", lambda: lpam_apply(at_tip, "lpam-cold"),
                      prepare=fresh("lpam-cold")),
        ],
        reference="git clone --depth 1", mine="lpam apply")
    moved = Scenario(
        key="pin_moved", title="Pin moved one commit ahead (parent of the tip, then the tip)",
        contenders=[
            Contender("git fetch --depth 1 origin TIP",
                      fetch_tip("shallow", "--depth", "1"),
                      prepare=clone_of_parent("shallow", "--depth", "1")),
            # for scale: a client that has the whole history needs only the new objects
            Contender("git fetch origin TIP, full clone", fetch_tip("full-parent"),
                      prepare=clone_of_parent("full-parent")),
            Contender("lpam apply (re-pinned)", lambda: lpam_apply(at_tip, "lpam-moved"),
                      prepare=lpam_at_parent),
        ],
        reference="git fetch --depth 1 origin TIP", mine="lpam apply (re-pinned)")
    return [cold, moved]


def measure(fx: Fixture, sections: list[Scenario], reps: int) -> None:
    """Round-robin: round 0 warms up and is not counted, then `reps` rounds of every tool."""
    for rnd in range(reps + 1):
        log(f"  round {rnd}/{reps}{' (warm-up)' if rnd == 0 else ''}")
        for section in sections:
            for c in section.contenders:
                mark = fx.relay.mark()
                c.prepare()
                prepared = fx.relay.since(mark)
                mark = fx.relay.mark()
                started = time.perf_counter()
                c.run()
                elapsed = time.perf_counter() - started
                traffic = fx.relay.since(mark)
                if rnd:
                    c.traffic.append(traffic)
                    c.prepared.append(prepared)
                    c.seconds.append(elapsed)


def median(values: Sequence[float]) -> float:
    return float(statistics.median(values))


def down(section: Scenario, name: str, *, first_pin: bool = False) -> float:
    """Median bytes server→client of one contender (with its first pin's, if asked)."""
    c = next(c for c in section.contenders if c.name == name)
    return median([t.to_client + (p.to_client if first_pin else 0)
                   for t, p in zip(c.traffic, c.prepared)])


def ratios(section: Scenario) -> dict[str, float]:
    """lpam's bytes server→client over the reference's: alone, and with the first pin."""
    return {key: down(section, section.mine, first_pin=first) /
            down(section, section.reference, first_pin=first)
            for key, first in (("bytes", False), ("bytes_with_first_pin", True))}


def summary(sections: list[Scenario]) -> dict[str, object]:
    out: dict[str, object] = {}
    for s in sections:
        rows = {c.name: {"to_client": [t.to_client for t in c.traffic],
                         "to_server": [t.to_server for t in c.traffic],
                         "connections": [t.connections for t in c.traffic],
                         "seconds": c.seconds,
                         "prepare_to_client": [t.to_client for t in c.prepared]}
                for c in s.contenders}
        out[s.key] = {"title": s.title, "reference": s.reference, "rows": rows,
                        "mine": s.mine, "ratio": ratios(s)}
    return out


def table(section: Scenario) -> str:
    ref_bytes = down(section, section.reference)
    lines = [f"### {section.title}", "",
             f"| tool | server→client bytes | client→server bytes | x {section.reference} "
             "| connections | median s | before it: first pin, server→client bytes |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for c in section.contenders:
        got = down(section, c.name)
        up = median([t.to_server for t in c.traffic])
        conns = sorted({t.connections for t in c.traffic})
        lines.append(f"| {c.name} | {got:,.0f} | {up:,.0f} | {got / ref_bytes:.2f} "
                     f"| {'/'.join(map(str, conns))} | {median(c.seconds):.3f} "
                     f"| {median([t.to_client for t in c.prepared]):,.0f} |")
    ratio = ratios(section)
    lines += ["", f"{section.mine} / {section.reference}, bytes server→client: "
                  f"{ratio['bytes']:.2f}"]
    if any(t.to_client for c in section.contenders for t in c.prepared):
        lines[-1] += f"; with the first pin's bytes: {ratio['bytes_with_first_pin']:.2f}"
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.wire",
                                     description="bytes on the wire: lpam, git, vcs")
    parser.add_argument("--reps", type=int, default=3, help="counted rounds (default 3)")
    parser.add_argument("--commits", type=int, default=300, help="commits (default 300)")
    parser.add_argument("--files", type=int, default=20, help="files rewritten (default 20)")
    parser.add_argument("--json", action="store_true", help="JSON instead of Markdown")
    args = parser.parse_args(argv)
    if not 1 <= args.reps <= 50 or not 2 <= args.commits <= 5000 or not 1 <= args.files <= 500:
        parser.error("keep --reps <= 50, 2 <= --commits <= 5000, --files <= 500")

    with tempfile.TemporaryDirectory(prefix="lpam-bench-wire-") as name:
        tmp = Path(name)
        home = tmp / "home"
        home.mkdir()
        env = git_env(home)
        env["PYTHONPATH"] = str(TOP)  # lpam runs this checkout's code
        with GitDaemon(tmp / "served", home=home) as daemon, Relay(daemon.port) as relay:
            log(f"building one repository of {args.commits} commits ...")
            hashes = build(daemon.base, tmp / "work", home, commits=args.commits,
                           files=args.files)
            fx = Fixture(tmp, env, relay)
            sections = scenarios(fx, hashes)
            measure(fx, sections, args.reps)

    if args.json:
        print(json.dumps({"reps": args.reps, "commits": args.commits, "files": args.files,
                          "vcs": fx.vcs, "scenarios": summary(sections)}, indent=2))
        return 0
    print(f"\n{args.reps} counted rounds after one warm-up; one repository of {args.commits} "
          f"commits over {args.files} files (~2 KB of random base64 each), through a "
          f"counting relay to a loopback git daemon. Bytes are TCP payload, medians. "
          f"vcs is {fx.vcs}.\n")
    for section in sections:
        print(table(section) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
