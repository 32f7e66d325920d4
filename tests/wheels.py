"""Pure-Python wheels written by hand, and a hermetic pip, for tests that run a real pip
with no network.

A wheel is a zip of the modules and a `.dist-info` folder (METADATA, WHEEL, and RECORD
with each file's sha256); nothing needs building. The distribution's name and its module's
name are independent, as with `python-can` providing `can`, which is what lpam must cope
with.
"""

from __future__ import annotations

import base64
import hashlib
import importlib.metadata
import os
import shlex
import subprocess
import zipfile
from collections.abc import Sequence
from pathlib import Path

import pytest
from packaging.utils import canonicalize_name

from schemas.dependency import requirement_name

_EPOCH = (2020, 1, 1, 0, 0, 0)  # fixed times: the same arguments give the same bytes


def write_wheel(folder: Path, name: str, version: str, *, module: str, source: str = "",
                requires: Sequence[str] = ()) -> Path:
    """Write the wheel of distribution `name` at `version` into `folder`; its path.

    `module` is the importable name it provides (`a.b` makes package `a` with module `b`),
    holding `source`; `requires` become its Requires-Dist lines (markers allowed, such as
    `x; extra == "fast"`)."""
    stem = f"{str(canonicalize_name(name)).replace('-', '_')}-{version}"
    info = f"{stem}.dist-info"
    parts = module.split(".")
    files = {f"{'/'.join(parts[:i])}/__init__.py": "" for i in range(1, len(parts))}
    files[f"{'/'.join(parts)}.py"] = source
    metadata = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"
    metadata += "".join(f"Requires-Dist: {requirement}\n" for requirement in requires)
    extras = sorted({r.split('extra == "', 1)[1].split('"')[0] for r in requires
                     if 'extra == "' in r})
    metadata += "".join(f"Provides-Extra: {extra}\n" for extra in extras)
    files[f"{info}/METADATA"] = metadata
    files[f"{info}/WHEEL"] = (
        "Wheel-Version: 1.0\nGenerator: lpam-tests\nRoot-Is-Purelib: true\nTag: py3-none-any\n"
    )
    record = [f"{path},sha256={_digest(text.encode())},{len(text.encode())}"
              for path, text in files.items()]
    files[f"{info}/RECORD"] = "\n".join([*record, f"{info}/RECORD,,"]) + "\n"
    folder.mkdir(parents=True, exist_ok=True)
    wheel = folder / f"{stem}-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        for path, text in files.items():
            archive.writestr(zipfile.ZipInfo(path, _EPOCH), text)
    return wheel


def _digest(data: bytes) -> str:
    return base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def user_site(python: str) -> Path:
    """Where the interpreter looks for the user's packages under this test's HOME."""
    out = subprocess.run([python, "-c", "import site; print(site.getusersitepackages())"],
                         capture_output=True, text=True, check=True)
    return Path(out.stdout.strip())


def unpack(wheel: Path, site: Path) -> None:
    """Install a pure wheel the way pip lays it out: its files, unpacked."""
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(site)


def env_holds(env: Path) -> dict[str, str]:
    sites = [str(path) for path in env.glob("lib/python*/site-packages")]
    return {requirement_name(dist.metadata["Name"]): dist.version
            for dist in importlib.metadata.distributions(path=sites)} if sites else {}


def pip_runs_in(log: list[str]) -> list[list[str]]:
    """The requirements each pip run of the log was given, as a user reads them there."""
    runs = []
    for line in log:
        if line.startswith("$ ") and " -m pip " in line:
            argv = shlex.split(line[2:])
            runs.append(argv[argv.index("--no-input") + 1:])
    return runs


def hermetic_pip(monkeypatch: pytest.MonkeyPatch, wheels: Path) -> None:
    """pip sees only `wheels`: no index, no configuration file, no cache outside HOME."""
    for name in list(os.environ):
        if name.startswith("PIP_") or name.startswith("PYTHON") or name == "XDG_CACHE_HOME":
            monkeypatch.delenv(name)
    monkeypatch.setenv("PIP_NO_INDEX", "1")
    monkeypatch.setenv("PIP_FIND_LINKS", str(wheels))
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)
    wheels.mkdir(exist_ok=True)
