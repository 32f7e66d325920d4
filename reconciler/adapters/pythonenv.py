"""Virtual environments for apps' pip requirements (the `PythonEnvs` port).

One environment per *set* of requirements, named by a hash of the set, so every app and
generation asking for the same set shares it and a rollback finds its environment still
there. Each is made from the system's interpreter with `--system-site-packages`: on the
Pi, apps must keep seeing apt's and ROS's Python packages, and pip installs only what the
system does not already provide.

What is "already provided" is read from distribution metadata over the interpreter's
`sys.path`, never by importing: importing an app's dependency runs its code (it may open
the CAN bus), and a distribution's module often has another name (`python-can` is `can`).

An environment is usable only once its marker (`.lpam-ready`) is written, after pip
succeeded and the files are on disk; a directory without it is what a power cut or a
failed install left behind, and is rebuilt. pip is lpam's own, aimed at the environment
with `--python` (the environment itself has no pip), and reads its index, wheel folder and
offline switch from lpam's environment (PIP_INDEX_URL, PIP_FIND_LINKS, PIP_NO_INDEX).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import InvalidVersion

from reconciler.adapters.command import run_streamed
from reconciler.base.atomic import write_atomic
from reconciler.base.errors import DependencyError
from reconciler.engine.execution.ports import Log

MARKER = ".lpam-ready"
_NAME = re.compile(r"^[0-9a-f]{16}$")
_SYS_PATH = "import json, sys; print(json.dumps(sys.path))"
PIP_HINT = (
    "check that the package index or wheel folder pip uses has the requirement in a version "
    "that fits (PIP_INDEX_URL, PIP_FIND_LINKS, PIP_NO_INDEX in lpam's environment) and "
    "that the name is right in the app's catalog; the running app is untouched"
)


def normalise(requirement: str) -> str:
    """The form pip compares requirements in: `Shapely[b,A] <3,>=2` → `shapely[a,b]<3,>=2`."""
    parsed = Requirement(requirement)
    extras = ",".join(sorted(canonicalize_name(extra) for extra in parsed.extras))
    return f"{canonicalize_name(parsed.name)}{f'[{extras}]' if extras else ''}{parsed.specifier}"


def env_name(requirements: Iterable[str]) -> str:
    """The folder name of the environment for a set of requirements: the same set, in any
    order or spelling, shares one environment."""
    text = "\n".join(sorted({normalise(requirement) for requirement in requirements}))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def satisfies(requirement: Requirement, version: str | None) -> bool:
    """Whether an installed `version` (None: not installed) meets the requirement. A
    pre-release counts: it is what is installed, and pip's rule is about what to choose."""
    if version is None:
        return False
    if not requirement.specifier:
        return True
    try:
        return requirement.specifier.contains(version, prereleases=True)
    except InvalidVersion:  # an old distribution's non-PEP 440 version: cannot tell
        return False


def lacking(requirements: Sequence[str], path: Sequence[str]) -> list[str]:
    """The requirements not met by the distributions found on `path`, in the order given.
    The first distribution of a name on the path wins, as it does for an import."""
    found: dict[str, importlib.metadata.Distribution] = {}
    for dist in importlib.metadata.distributions(path=list(path)):
        name = dist.metadata["Name"]
        if name:
            found.setdefault(canonicalize_name(name), dist)
    return [text for text in requirements if not _met(Requirement(text), found, set())]


def _met(requirement: Requirement, found: Mapping[str, importlib.metadata.Distribution],
         seen: set[str]) -> bool:
    """The distribution is there in a fitting version, and so is what its requested extras
    add (apt installs a package's plain dependencies, but never an extra's)."""
    name = canonicalize_name(requirement.name)
    dist = found.get(name)
    if not satisfies(requirement, dist.version if dist else None):
        return False
    assert dist is not None
    for extra in sorted(canonicalize_name(extra) for extra in requirement.extras):
        if f"{name}[{extra}]" in seen:
            continue
        seen.add(f"{name}[{extra}]")
        for text in dist.requires or []:
            needed = Requirement(text)
            if needed.marker is None or not needed.marker.evaluate({"extra": extra}):
                continue
            if needed.marker.evaluate({"extra": ""}):
                continue  # a plain dependency: the distribution's installer saw to it
            if not _met(needed, found, seen):
                return False
    return True


def lpam_has_pip() -> bool:
    """Whether lpam's own interpreter can run pip; without it, each environment gets a
    pip of its own (slower to make, and one more copy of pip per environment)."""
    return importlib.util.find_spec("pip") is not None


def _default_python() -> str:
    return "/usr/bin/python3" if os.path.exists("/usr/bin/python3") else \
        shutil.which("python3") or "python3"


class VenvPythonEnvs:
    """The `PythonEnvs` port with `python -m venv` and pip, environments under `base`."""

    def __init__(self, base: Path, *, python: str | None = None,
                 timeout: float = 1800.0) -> None:
        self.base = base
        self.python = python or _default_python()
        self.timeout = timeout

    def location(self, requirements: Sequence[str]) -> Path:
        return self.base / env_name(requirements)

    def ready(self, requirements: Sequence[str]) -> bool:
        return (self.location(requirements) / MARKER).is_file()

    def unsatisfied(self, requirements: Sequence[str]) -> list[str]:
        """What the environment would lack: judged over the environment's `sys.path` once it
        is ready, else over the system interpreter's (what the environment would inherit)."""
        ready = self.ready(requirements)
        python = _env_python(self.location(requirements)) if ready else self.python
        return lacking(requirements, _sys_path(python))

    def ensure(self, requirements: Sequence[str], *, log: Log) -> Path:
        """The ready environment for `requirements`, made and filled as needed. A ready one
        that has come to lack something (apt removed it) gets it installed in place and
        keeps its marker: rebuilding would pull the environment from under a running app."""
        env = self.location(requirements)
        deadline = time.monotonic() + self.timeout
        if env.is_dir() and not (env / MARKER).is_file():
            log(f"removing the unfinished Python environment {env}")
            _remove(env)
        own_pip = lpam_has_pip()
        if not env.is_dir():
            venv = [self.python, "-m", "venv", "--system-site-packages", str(env)]
            if own_pip:
                venv.insert(4, "--without-pip")
            self.base.mkdir(parents=True, exist_ok=True)
            _run(venv, log=log, deadline=deadline,
                 failed=f"cannot create the Python environment {env}",
                 hint=f"check that {self.python} can run `-m venv` (Debian: the python3-venv "
                 "package)")
        missing = lacking(requirements, _sys_path(_env_python(env)))
        if missing:
            self._install(env, missing, own_pip=own_pip, log=log, deadline=deadline)
        if not (env / MARKER).is_file():
            os.sync()  # pip does not fsync: the marker must not reach the disk before the files
            write_atomic(env / MARKER, json.dumps(
                {"requirements": sorted({normalise(text) for text in requirements})},
                indent=2) + "\n")
        return env

    def _install(self, env: Path, missing: list[str], *, own_pip: bool, log: Log,
                 deadline: float) -> None:
        pip = [sys.executable, "-m", "pip", "--python", str(_env_python(env))] if own_pip \
            else [str(_env_python(env)), "-m", "pip"]
        argv = [*pip, "install", "--disable-pip-version-check", "--no-input", *missing]
        _run(argv, log=log, deadline=deadline,
             failed=f"pip could not install {', '.join(missing)}", hint=PIP_HINT)

    def collect(self, keep: set[Path]) -> None:
        """Remove the environments not in `keep`. Only folders named like an environment
        are touched, whatever else a mistaken `base` may hold."""
        if not self.base.is_dir():
            return
        for entry in self.base.iterdir():
            if entry not in keep and _NAME.match(entry.name) and entry.is_dir() \
                    and not entry.is_symlink():
                _remove(entry)


def _env_python(env: Path) -> Path:
    return env / "bin" / "python"


def _sys_path(python: str | Path) -> list[str]:
    """The interpreter's `sys.path` as an app started from a clean environment sees it:
    without lpam's own PYTHON* variables, and without the working directory."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    try:
        result = subprocess.run([str(python), "-c", _SYS_PATH], capture_output=True,
                                text=True, timeout=60, env=env, cwd="/", check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise DependencyError(f"cannot ask {python} for its sys.path: {exc}",
                              hint="check that the interpreter lpam uses exists") from None
    if result.returncode != 0:
        raise DependencyError(
            f"cannot ask {python} for its sys.path: exit {result.returncode}",
            details=result.stderr.splitlines(),
            hint="a broken environment: remove it and apply again",
        )
    try:  # the last line: a sitecustomize may print before it
        paths = json.loads(result.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        raise DependencyError(f"{python} did not say what its sys.path is",
                              details=result.stdout.splitlines()) from None
    return [path for path in paths if isinstance(path, str) and os.path.isabs(path)]


def _run(argv: list[str], *, log: Log, deadline: float, failed: str, hint: str) -> None:
    """Run `argv`; DependencyError `failed: why` when it fails (exit code -9 when it was
    killed at the deadline)."""
    outcome = run_streamed(argv, log=log, deadline=deadline)
    code = -9 if outcome.code is None else outcome.code
    if code != 0:
        raise DependencyError(f"{failed}: {_cause(outcome.tail, code)}", details=outcome.tail,
                              hint=hint)


def _remove(env: Path) -> None:
    """Marker first, so that an environment half removed by a power cut is not `ready`."""
    (env / MARKER).unlink(missing_ok=True)
    shutil.rmtree(env)


def _cause(tail: list[str], code: int) -> str:
    """pip's own reason (its last `ERROR:` line, e.g. `No matching distribution found for
    X`), else the last line it wrote."""
    errors = [line for line in tail if line.startswith("ERROR:")]
    if errors:
        return errors[-1].removeprefix("ERROR:").strip()
    return tail[-1].strip() if tail else f"exit code {code}"
