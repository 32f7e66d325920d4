"""One contract for the Python environments of apps' pip requirements: real virtual
environments filled by a real pip (VenvPythonEnvs) and the in-memory twin
(MemoryPythonEnvs) that the planner's fast tests use.

What the executor relies on is written once for both: one location per set of
requirements however it is spelled, `unsatisfied` saying what the environment would lack
(nothing once it is ensured), pip asked for exactly what is missing and not run at all
when nothing is, a requirement pip cannot find failing with its name and leaving nothing
marked ready, and `collect` removing the environments not kept.

The real world is hermetic: pip reads only a wheel folder the test writes (PIP_NO_INDEX,
PIP_FIND_LINKS, no configuration file), "the system" is the user site-packages under the
test's HOME (a `--system-site-packages` environment sees it, as it sees apt's packages),
and every environment lives under the test's temporary folder.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from reconciler.adapters.pythonenv import MARKER, VenvPythonEnvs
from reconciler.adapters.pythonenv_memory import MemoryPythonEnvs
from reconciler.base.errors import DependencyError
from reconciler.engine.execution.ports import PythonEnvs
from tests.wheels import env_holds, hermetic_pip, pip_runs_in, unpack, user_site, write_wheel

ALPHA = "lpam-demo-alpha"
BETA = "lpam-demo-beta"
SYSTEM = "lpam-demo-system"
NOWHERE = "lpam-demo-nowhere"


@dataclass
class World:
    """An implementation, and how to shape what the system and the package index hold."""

    envs: PythonEnvs
    real: bool
    offer: Callable[[str, str], None]  # pip can install this distribution at this version
    provide: Callable[[str, str], None]  # the system already has it
    holds: Callable[[Path], dict[str, str]]  # what an environment itself installed
    pip_runs: Callable[[], list[list[str]]]  # the requirements of each pip run so far
    log: list[str] = field(default_factory=list)


def _venv(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[World]:
    wheels = tmp_path / "wheels"
    hermetic_pip(monkeypatch, wheels)
    envs = VenvPythonEnvs(tmp_path / "var/lib/lpam/venvs")
    site = user_site(envs.python)
    assert str(site).startswith(str(tmp_path.parent)), "HOME must be the test's own"

    def offer(name: str, version: str) -> None:
        write_wheel(wheels, name, version, module=name.replace("-", "_"))

    def provide(name: str, version: str) -> None:
        unpack(write_wheel(tmp_path / "system-wheels", name, version,
                           module=name.replace("-", "_")), site)

    log: list[str] = []
    yield World(envs, True, offer, provide, env_holds, lambda: pip_runs_in(log), log)


def _memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[World]:
    twin = MemoryPythonEnvs({}, {}, base=tmp_path / "var/lib/lpam/venvs")
    yield World(twin, False, twin.available.__setitem__, twin.system.__setitem__,
                lambda env: dict(twin.envs.get(env, {})),
                lambda: [list(args) for kind, args in twin.calls if kind == "pip"])


@pytest.fixture(params=[_venv, _memory], ids=["venv", "memory"])
def world(request: pytest.FixtureRequest, tmp_path: Path,
          monkeypatch: pytest.MonkeyPatch) -> Iterator[World]:
    yield from request.param(tmp_path, monkeypatch)


# -- the contract -----------------------------------------------------------------------


def test_one_location_per_set_however_spelled(world: World, tmp_path: Path) -> None:
    envs = world.envs
    first = envs.location(["Shapely>=2,<3", "cantools", "requests[socks,Brotli]"])
    assert first.parent == tmp_path / "var/lib/lpam/venvs"
    assert envs.location(["CANTOOLS", "requests[brotli,socks]", "shapely<3,>=2",
                          "cantools"]) == first
    assert envs.location(["cantools", "shapely>=2,<3", "requests[socks]"]) != first
    assert envs.location(["cantools", "shapely>=2,<4", "requests[socks,Brotli]"]) != first
    assert envs.location(["python_can"]) == envs.location(["Python.Can"])
    assert not first.exists(), "asking where is not making"


def test_unsatisfied_before_and_after_ensure(world: World) -> None:
    world.offer(ALPHA, "1.0")
    world.provide(SYSTEM, "1.0")
    requirements = [ALPHA, SYSTEM]
    assert world.envs.unsatisfied(requirements) == [ALPHA]
    assert not world.envs.ready(requirements)

    env = world.envs.ensure(requirements, log=world.log.append)

    assert env == world.envs.location(requirements)
    assert world.envs.ready(requirements)
    assert world.envs.unsatisfied(requirements) == []
    assert not world.real or (env / MARKER).is_file()


def test_ensure_installs_only_what_is_missing(world: World) -> None:
    world.offer(ALPHA, "1.0")
    world.offer(BETA, "2.0")
    world.offer(SYSTEM, "9.0")  # pip could install a newer one; the system's will do
    world.provide(SYSTEM, "1.0")
    requirements = [BETA, SYSTEM, "LPAM_demo.alpha>=1"]

    env = world.envs.ensure(requirements, log=world.log.append)

    assert world.pip_runs() == [[BETA, "LPAM_demo.alpha>=1"]]
    assert world.holds(env) == {ALPHA: "1.0", BETA: "2.0"}


def test_ensure_runs_no_pip_when_the_system_has_everything(world: World) -> None:
    world.provide(SYSTEM, "1.0")
    assert world.envs.unsatisfied([f"{SYSTEM}>=1"]) == []
    assert not world.envs.ready([f"{SYSTEM}>=1"]), "the environment must still be made"

    env = world.envs.ensure([f"{SYSTEM}>=1"], log=world.log.append)

    assert world.pip_runs() == []
    assert world.envs.ready([f"{SYSTEM}>=1"])
    assert world.holds(env) == {}
    assert not world.real or (env / "bin" / "python").exists()


def test_a_second_ensure_installs_nothing(world: World) -> None:
    world.offer(ALPHA, "1.0")
    first = world.envs.ensure([ALPHA], log=world.log.append)
    second = world.envs.ensure([ALPHA], log=world.log.append)
    assert first == second
    assert world.pip_runs() == [[ALPHA]]


def test_an_older_system_version_is_shadowed_by_the_environments(world: World) -> None:
    world.provide(ALPHA, "1.0")
    world.offer(ALPHA, "2.0")
    assert world.envs.unsatisfied([f"{ALPHA}>=2"]) == [f"{ALPHA}>=2"]
    assert world.envs.unsatisfied([f"{ALPHA}>=1"]) == []

    env = world.envs.ensure([f"{ALPHA}>=2"], log=world.log.append)

    assert world.holds(env) == {ALPHA: "2.0"}
    assert world.envs.unsatisfied([f"{ALPHA}>=2"]) == []


def test_a_requirement_pip_cannot_find_fails_naming_it(world: World) -> None:
    world.offer(ALPHA, "1.0")
    requirements = [ALPHA, NOWHERE]

    with pytest.raises(DependencyError) as caught:
        world.envs.ensure(requirements, log=world.log.append)

    assert NOWHERE in caught.value.message
    assert "No matching distribution found for" in caught.value.message
    assert caught.value.details
    assert caught.value.hint is not None and "PIP_FIND_LINKS" in caught.value.hint
    assert not world.envs.ready(requirements)
    assert NOWHERE in world.envs.unsatisfied(requirements)
    if world.real:
        assert not (world.envs.location(requirements) / MARKER).exists()

    world.offer(NOWHERE, "0.1")  # the wheel is added; the next apply gets through
    world.envs.ensure(requirements, log=world.log.append)
    assert world.envs.ready(requirements)
    assert world.envs.unsatisfied(requirements) == []


def test_a_version_pip_does_not_have_fails_naming_it(world: World) -> None:
    world.offer(ALPHA, "1.0")
    with pytest.raises(DependencyError) as caught:
        world.envs.ensure([f"{ALPHA}>=2"], log=world.log.append)
    assert f"{ALPHA}>=2" in caught.value.message
    assert not world.envs.ready([f"{ALPHA}>=2"])


def test_collect_removes_what_is_not_kept(world: World) -> None:
    world.offer(ALPHA, "1.0")
    world.offer(BETA, "1.0")
    kept = world.envs.ensure([ALPHA], log=world.log.append)
    dropped = world.envs.ensure([BETA], log=world.log.append)

    world.envs.collect({kept})

    assert world.envs.ready([ALPHA]) and not world.envs.ready([BETA])
    assert world.envs.unsatisfied([BETA]) == [BETA]
    assert not world.real or (kept.is_dir() and not dropped.exists())
    world.envs.collect(set())
    assert not world.envs.ready([ALPHA])
    assert not world.real or not kept.exists()
