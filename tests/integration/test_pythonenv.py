"""What only real virtual environments and a real pip can show (the shared behaviour is in
tests/contract/test_python_envs.py): a distribution found by its metadata whatever its
module is called and without running its code, an environment reused with no pip and no
wheel left, version specifiers judged against what is installed, an environment cut off
half-made rebuilt, pip's own words in the error, and pip killed at the deadline.

pip reads only the test's wheel folder (or a server on 127.0.0.1 that never answers);
"the system" is the user site-packages under the test's HOME.
"""

from __future__ import annotations

import os
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from reconciler.adapters.pythonenv import MARKER, VenvPythonEnvs
from reconciler.base.errors import DependencyError
from tests.wheels import env_holds, hermetic_pip, pip_runs_in, unpack, user_site, write_wheel

SPEEDO = "lpam-demo-speedo"  # provides the module `speedo`, not `lpam_demo_speedo`


def ignore(line: str) -> None:
    """A log for tests that do not read it."""


@dataclass
class Car:
    envs: VenvPythonEnvs
    wheels: Path
    site: Path  # the system's packages
    tmp: Path

    def provide(self, name: str, version: str, *, module: str, source: str = "",
                requires: tuple[str, ...] = ()) -> None:
        unpack(write_wheel(self.tmp / "system-wheels", name, version, module=module,
                           source=source, requires=requires), self.site)

    def python(self, env: Path, code: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(env / "bin" / "python"), "-c", code], capture_output=True,
                              text=True, cwd=self.tmp, check=False)


@pytest.fixture
def car(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Car]:
    wheels = tmp_path / "wheels"
    hermetic_pip(monkeypatch, wheels)
    envs = VenvPythonEnvs(tmp_path / "var/lib/lpam/venvs")
    site = user_site(envs.python)
    assert str(site).startswith(str(tmp_path.parent)), "HOME must be the test's own"
    yield Car(envs, wheels, site, tmp_path)


def test_a_distribution_is_known_by_its_metadata_and_never_imported(car: Car) -> None:
    flag = car.tmp / "imported"
    source = f"import pathlib\npathlib.Path({str(flag)!r}).write_text('yes')\nVALUE = 42\n"
    write_wheel(car.wheels, SPEEDO, "1.0", module="speedo", source=source)
    assert car.envs.unsatisfied([SPEEDO]) == [SPEEDO]

    log: list[str] = []
    env = car.envs.ensure([SPEEDO], log=log.append)

    assert car.envs.unsatisfied([SPEEDO]) == []
    assert not flag.exists(), "lpam ran the distribution's code to judge it"
    assert car.python(env, "import lpam_demo_speedo").returncode != 0
    imported = car.python(env, "import speedo; print(speedo.VALUE)")
    assert imported.stdout.strip() == "42", imported.stderr
    assert flag.read_text() == "yes"
    assert any("Successfully installed lpam-demo-speedo-1.0" in line for line in log)


def test_an_importable_module_without_metadata_does_not_count(car: Car) -> None:
    car.site.mkdir(parents=True, exist_ok=True)
    (car.site / "speedo.py").write_text("VALUE = 'a stray copy'\n")
    (car.site / "lpam_demo_speedo.py").write_text("VALUE = 'a stray copy'\n")
    assert car.envs.unsatisfied([SPEEDO]) == [SPEEDO]


def test_a_ready_environment_is_reused_with_no_pip_and_no_wheels(car: Car) -> None:
    write_wheel(car.wheels, SPEEDO, "1.0", module="speedo", source="VALUE = 1\n")
    first = car.envs.ensure([SPEEDO], log=ignore)
    for wheel in car.wheels.iterdir():
        wheel.unlink()

    log: list[str] = []
    again = VenvPythonEnvs(car.envs.base)  # the next apply
    assert again.ready([SPEEDO]) and again.unsatisfied([SPEEDO]) == []
    assert again.ensure([SPEEDO], log=log.append) == first

    assert [line for line in log if line.startswith("$ ")] == [], "no venv, no pip"
    assert car.python(first, "import speedo; print(speedo.VALUE)").stdout.strip() == "1"


def test_version_specifiers_are_judged_against_the_installed_version(car: Car) -> None:
    car.provide(SPEEDO, "1.0", module="speedo")
    car.provide("lpam-demo-beta", "2.0b1", module="beta")
    envs = car.envs

    assert envs.unsatisfied([f"{SPEEDO}>=2"]) == [f"{SPEEDO}>=2"]
    assert envs.unsatisfied([f"{SPEEDO}<1"]) == [f"{SPEEDO}<1"]
    assert envs.unsatisfied([f"{SPEEDO}!=1.0"]) == [f"{SPEEDO}!=1.0"]
    assert envs.unsatisfied([f"{SPEEDO}>=1,<2", f"{SPEEDO}==1.0", f"{SPEEDO}~=1.0"]) == []
    assert envs.unsatisfied(["lpam-demo-beta>=1.5"]) == [], "an installed pre-release counts"
    assert envs.unsatisfied(["lpam-demo-beta>=2"]) == ["lpam-demo-beta>=2"]
    assert envs.unsatisfied(["lpam-demo-zzz", f"{SPEEDO}>=1", "lpam-demo-aaa", "Lpam_Demo_Speedo"]
                            ) == ["lpam-demo-zzz", "lpam-demo-aaa"], "in the order given"


def test_an_extra_needs_what_it_adds(car: Car) -> None:
    needs = ('lpam-demo-turbo; extra == "turbo"',)
    car.provide("lpam-demo-fast", "1.0", module="fast", requires=needs)
    write_wheel(car.wheels, "lpam-demo-fast", "1.0", module="fast", requires=needs)
    write_wheel(car.wheels, "lpam-demo-turbo", "1.0", module="turbo")
    assert car.envs.unsatisfied(["lpam-demo-fast"]) == []
    assert car.envs.unsatisfied(["lpam-demo-fast[turbo]"]) == ["lpam-demo-fast[turbo]"]

    log: list[str] = []
    env = car.envs.ensure(["lpam-demo-fast[turbo]"], log=log.append)

    assert pip_runs_in(log) == [["lpam-demo-fast[turbo]"]]
    assert env_holds(env) == {"lpam-demo-turbo": "1.0"}, "the system's lpam-demo-fast serves"
    assert car.envs.unsatisfied(["lpam-demo-fast[turbo]"]) == []


def test_an_environment_cut_off_half_made_is_rebuilt(car: Car) -> None:
    write_wheel(car.wheels, SPEEDO, "1.0", module="speedo", source="VALUE = 7\n")
    env = car.envs.location([SPEEDO])
    env.mkdir(parents=True)
    (env / "pyvenv.cfg").write_text("half written")  # the power went here

    assert not car.envs.ready([SPEEDO])
    car.envs.ensure([SPEEDO], log=ignore)
    assert car.envs.ready([SPEEDO])
    assert car.python(env, "import speedo; print(speedo.VALUE)").stdout.strip() == "7"

    (env / MARKER).unlink()  # cut off just before the marker: built, but not known good
    (env / "leftover").write_text("from the attempt that was cut off")
    assert not car.envs.ready([SPEEDO])
    log: list[str] = []
    car.envs.ensure([SPEEDO], log=log.append)
    assert car.envs.ready([SPEEDO]) and not (env / "leftover").exists()
    assert pip_runs_in(log) == [[SPEEDO]], "rebuilt from scratch, not trusted"


def test_pip_failure_is_reported_in_pips_words(car: Car) -> None:
    (car.wheels / "lpam_demo_broken-1.0-py3-none-any.whl").write_bytes(b"not a zip")

    with pytest.raises(DependencyError) as caught:
        car.envs.ensure(["lpam-demo-broken"], log=ignore)

    error = caught.value
    assert error.message.startswith("pip could not install lpam-demo-broken: ")
    assert "lpam_demo_broken-1.0-py3-none-any.whl is invalid" in error.message
    assert "is invalid" in error.details[-1]
    assert "  | ERROR: Wheel 'lpam-demo-broken'" in error.render()
    assert not car.envs.ready(["lpam-demo-broken"])


def _pip_processes(env: Path) -> list[int]:
    """Processes still running with the environment in their command line."""
    found = []
    for entry in os.listdir("/proc"):
        try:
            cmdline = Path(f"/proc/{entry}/cmdline").read_bytes()
            state = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[-1].split()[0]
        except OSError:
            continue
        if os.fsencode(str(env)) in cmdline and state != "Z":
            found.append(int(entry))
    return found


def test_a_pip_that_hangs_is_killed_at_the_deadline(car: Car,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    with socket.socket() as server:  # accepts connections, never answers
        server.bind(("127.0.0.1", 0))
        server.listen(8)
        monkeypatch.setenv("PIP_FIND_LINKS", f"http://127.0.0.1:{server.getsockname()[1]}/")
        monkeypatch.setenv("PIP_DEFAULT_TIMEOUT", "120")
        envs = VenvPythonEnvs(car.envs.base, timeout=4)
        env = envs.location([SPEEDO])
        started = time.monotonic()
        with pytest.raises(DependencyError) as caught:
            envs.ensure([SPEEDO], log=ignore)
        took = time.monotonic() - started
    assert "did not finish" in caught.value.message and SPEEDO in caught.value.message
    assert took < 4 + 5 + 2, f"took {took:.1f} s"
    assert _pip_processes(env) == []
    assert not envs.ready([SPEEDO])


def test_without_pip_in_lpam_each_environment_gets_its_own(
        car: Car, monkeypatch: pytest.MonkeyPatch) -> None:
    ensurepip = subprocess.run([car.envs.python, "-m", "ensurepip", "--version"],
                               capture_output=True, check=False)
    if ensurepip.returncode != 0:
        pytest.skip(f"{car.envs.python} has no ensurepip (Debian: python3-venv)")
    monkeypatch.setattr("reconciler.adapters.pythonenv.lpam_has_pip", lambda: False)
    write_wheel(car.wheels, SPEEDO, "1.0", module="speedo", source="VALUE = 3\n")

    log: list[str] = []
    env = car.envs.ensure([SPEEDO], log=log.append)

    assert (env / "bin" / "pip").exists()
    assert any(line.startswith(f"$ {env}/bin/python -m pip install") for line in log), log
    assert car.python(env, "import speedo; print(speedo.VALUE)").stdout.strip() == "3"
    assert car.envs.unsatisfied([SPEEDO]) == []
