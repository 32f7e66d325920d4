"""Build an offline installer of lpam for the cars: a folder of wheels for a Raspberry Pi.

Run on a machine with internet (a laptop), carry the folder to the car (USB stick), then
on the car:  python3 -m venv /opt/lpam
             /opt/lpam/bin/pip install --no-index --find-links WHEELHOUSE lpam

    python3 scripts/wheelhouse.py OUT [--python-version 3.9] [--glibc 2.31]
    python3 scripts/wheelhouse.py OUT --check-only      # check a wheelhouse already built

The defaults are the cars': 64-bit Raspberry Pi OS Bullseye, CPython 3.9 on aarch64 with
glibc 2.31. Only wheels are taken (`--only-binary=:all:`): a source distribution would need
a compiler and headers on the Pi, and the network to fetch its build requirements.

After downloading, the folder is checked: every file is a wheel that installs on that
platform, and pip resolves lpam and all it needs from the folder alone, for that platform,
with no index. pip evaluates requirement markers (`; python_version < "3.10"`) for the
Python it runs on, not the car's, so the closure is also computed here from the wheels'
own metadata with the car's environment, and what pip left out is downloaded too. Exit 0
when complete; 1 with what is missing otherwise. Needs `packaging` (lpam's own dependency:
run it with lpam's virtualenv, `.venv/bin/python scripts/wheelhouse.py OUT`).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import zipfile
from email.parser import Parser
from pathlib import Path

from packaging.markers import Marker
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parent.parent
_WHEEL = re.compile(
    r"^(?P<name>[^-]+)-(?P<version>[^-]+)(-(?P<build>\d[^-]*))?"
    r"-(?P<python>[^-]+)-(?P<abi>[^-]+)-(?P<platform>[^-]+)\.whl$"
)
_MANYLINUX = re.compile(r"^manylinux_(\d+)_(\d+)_(\w+)$")
_LEGACY = {"manylinux1": (2, 5), "manylinux2010": (2, 12), "manylinux2014": (2, 17)}


def platforms(glibc: tuple[int, int], arch: str) -> list[str]:
    """The platform tags pip on the car accepts, newest first (as `pip debug` lists them)."""
    tags = [f"manylinux_{glibc[0]}_{minor}_{arch}" for minor in range(glibc[1], 16, -1)]
    tags.append(f"manylinux2014_{arch}")
    return [*tags, f"linux_{arch}"]


def installs_on(wheel: str, python: tuple[int, int], glibc: tuple[int, int], arch: str) -> bool:
    """Whether a wheel file name carries a tag CPython `python` on `arch`/glibc accepts."""
    found = _WHEEL.match(wheel)
    if found is None:
        return False
    return any(_tag_fits(py, abi, python) and (plat == "any" or _platform_fits(plat, glibc, arch))
               for py in found["python"].split(".")
               for abi in found["abi"].split(".")
               for plat in found["platform"].split("."))


def _tag_fits(py: str, abi: str, python: tuple[int, int]) -> bool:
    major, minor = python
    cp = f"cp{major}{minor}"
    if abi == "none":
        return py in (f"py{major}", f"py{major}{minor}", cp)
    if abi == cp:
        return py == cp
    if abi == "abi3":  # the stable ABI: built for this CPython or an older one
        older = re.fullmatch(rf"cp{major}(\d+)", py)
        return older is not None and int(older[1]) <= minor
    return False


def _platform_fits(plat: str, glibc: tuple[int, int], arch: str) -> bool:
    if plat == f"linux_{arch}":
        return False  # not manylinux: built for some other Linux, may not load on the Pi
    for legacy, version in _LEGACY.items():
        if plat == f"{legacy}_{arch}":
            return version <= glibc
    found = _MANYLINUX.match(plat)
    if found is None:
        return False
    return found[3] == arch and (int(found[1]), int(found[2])) <= glibc


def environment(python: tuple[int, int], arch: str) -> dict[str, str]:
    """The marker environment of CPython `python` on Linux `arch` (PEP 508)."""
    version = f"{python[0]}.{python[1]}"
    return {"implementation_name": "cpython", "implementation_version": f"{version}.2",
            "os_name": "posix", "platform_machine": arch, "platform_release": "",
            "platform_system": "Linux", "platform_version": "", "python_full_version":
            f"{version}.2", "platform_python_implementation": "CPython",
            "python_version": version, "sys_platform": "linux", "extra": ""}


def _requires(wheel: Path) -> list[Requirement]:
    """The `Requires-Dist` lines of a wheel's METADATA."""
    with zipfile.ZipFile(wheel) as archive:
        name = next(n for n in archive.namelist()
                    if n.endswith(".dist-info/METADATA") and n.count("/") == 1)
        metadata = Parser().parsestr(archive.read(name).decode("utf-8"))
    return [Requirement(line) for line in metadata.get_all("Requires-Dist") or []]


def missing(out: Path, root: str, env: dict[str, str]) -> list[str]:
    """Requirements reached from `root` on the car (markers evaluated for `env`) that no
    wheel in `out` satisfies, as requirement strings pip can download."""
    return closure(out, root, env)[1]


def closure(out: Path, root: str, env: dict[str, str]) -> tuple[list[str], list[str]]:
    """(the wheels `root` needs on the car, as "name version"; what no wheel satisfies)."""
    wheels: dict[str, tuple[Version, Path]] = {}
    for path in out.glob("*.whl"):
        found = _WHEEL.match(path.name)
        if found:
            wheels[canonicalize_name(found["name"])] = (Version(found["version"]), path)
    lacking: list[str] = []
    reached: set[str] = set()
    todo = [(Requirement(root), "")]
    seen: set[tuple[str, str]] = set()
    while todo:
        requirement, extra = todo.pop()
        key = canonicalize_name(requirement.name)
        if (key, extra) in seen:
            continue
        seen.add((key, extra))
        have = wheels.get(key)
        if have is None or not requirement.specifier.contains(have[0], prereleases=True):
            lacking.append(str(Requirement(f"{requirement.name}{requirement.specifier}")))
            continue
        reached.add(f"{have[1].name.split('-')[0]} {have[0]}")
        for extra_name in ("", *requirement.extras):
            for need in _requires(have[1]):
                marker: Marker | None = need.marker
                if marker is None or marker.evaluate({**env, "extra": extra_name}):
                    todo.append((need, extra_name))
    return sorted(reached), sorted(set(lacking))


def _pip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", *args],
                          capture_output=True, text=True, check=False)


def _target(python: tuple[int, int], glibc: tuple[int, int], arch: str) -> list[str]:
    """pip options that make it pick and resolve for the car, not for this machine."""
    options = ["--only-binary=:all:", "--implementation", "cp",
               "--python-version", f"{python[0]}.{python[1]}",
               "--abi", f"cp{python[0]}{python[1]}"]
    for tag in platforms(glibc, arch)[:-1]:  # manylinux only
        options += ["--platform", tag]
    return options


def build(out: Path, python: tuple[int, int], glibc: tuple[int, int], arch: str) -> bool:
    out.mkdir(parents=True, exist_ok=True)
    print(f"building lpam's wheel into {out}")
    made = _pip("wheel", "--no-deps", "--wheel-dir", str(out), str(ROOT))
    if made.returncode != 0:
        print(made.stdout + made.stderr, file=sys.stderr)
        return False
    own = sorted(out.glob("lpam-*.whl"), key=lambda p: p.stat().st_mtime)[-1]
    print(f"downloading what lpam needs for CPython {python[0]}.{python[1]} on {arch} "
          f"(glibc {glibc[0]}.{glibc[1]}), wheels only")
    got = _pip("download", "--dest", str(out), *_target(python, glibc, arch), str(own))
    if got.returncode != 0:
        print(got.stdout + got.stderr, file=sys.stderr)
        print("the wheelhouse is incomplete: pip could not download a wheel of everything "
              "above for the car's platform", file=sys.stderr)
        return False
    for _ in range(10):  # each round adds what the car's markers need beyond pip's choice
        lacking = missing(out, "lpam", environment(python, arch))
        if not lacking:
            return True
        print(f"pip left out what the car needs: {', '.join(lacking)}; downloading it")
        got = _pip("download", "--dest", str(out), *_target(python, glibc, arch), *lacking)
        if got.returncode != 0:
            print(got.stdout + got.stderr, file=sys.stderr)
            return False
    return True


def check(out: Path, python: tuple[int, int], glibc: tuple[int, int], arch: str) -> bool:
    """Whether `out` installs lpam on the car with no index: every file a fitting wheel,
    and pip's resolver satisfied from the folder alone."""
    problems = [f"{p.name}: not a wheel (a source distribution needs a compiler on the car)"
                for p in sorted(out.iterdir()) if p.is_file() and p.suffix != ".whl"]
    wheels = sorted(p.name for p in out.glob("*.whl"))
    problems += [f"{w}: does not install on CPython {python[0]}.{python[1]} {arch}"
                 for w in wheels if not installs_on(w, python, glibc, arch)]
    if not any(w.startswith("lpam-") for w in wheels):
        problems.append("lpam's own wheel is missing")
    needed, lacking = closure(out, "lpam", environment(python, arch))
    problems += [f"{need}: needed on the car, no wheel in the folder satisfies it"
                 for need in lacking]
    print(f"the car (CPython {python[0]}.{python[1]}, {arch}) needs {len(needed)} of them:")
    print("  " + ", ".join(needed))
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        resolved = _pip("install", "--dry-run", "--ignore-installed", "--no-index",
                        "--find-links", str(out), "--target", str(Path(tmp) / "t"),
                        "--report", str(report), *_target(python, glibc, arch), "lpam")
        if resolved.returncode != 0:
            tail = (resolved.stdout + resolved.stderr).strip().splitlines()[-3:]
            problems.append("pip cannot install lpam from the folder alone: " + " / ".join(tail))
        else:
            chosen = json.loads(report.read_text())["install"]
            print(f"pip resolves lpam from the folder alone, with no index ({len(chosen)} "
                  "distributions; markers as this Python sees them)")
    for problem in problems:
        print(f"incomplete: {problem}", file=sys.stderr)
    if not problems:
        print(f"complete: {len(wheels)} wheels for CPython {python[0]}.{python[1]} on {arch}, "
              "no source distribution")
    return not problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the folder to fill (created if missing)")
    parser.add_argument("--python-version", default="3.9", help="the car's Python (3.9)")
    parser.add_argument("--glibc", default="2.31", help="the car's glibc (Bullseye: 2.31)")
    parser.add_argument("--arch", default="aarch64", help="the car's machine (aarch64)")
    parser.add_argument("--check-only", action="store_true", help="check, download nothing")
    args = parser.parse_args(argv)
    try:
        python = tuple(int(x) for x in args.python_version.split("."))[:2]
        glibc = tuple(int(x) for x in args.glibc.split("."))[:2]
    except ValueError:
        parser.error("--python-version and --glibc are numbers like 3.9 and 2.31")
    pv, gv = (python[0], python[1]), (glibc[0], glibc[1])
    if not args.check_only and not build(args.out, pv, gv, args.arch):
        return 1
    if not args.out.is_dir():
        print(f"{args.out}: no such folder", file=sys.stderr)
        return 1
    return 0 if check(args.out, pv, gv, args.arch) else 1


if __name__ == "__main__":
    sys.exit(main())
