"""One contract for the system package port: the real AptPackages (the machine's real
`dpkg-query`, and an `apt-get` on PATH that records its calls, because the test suite never
installs packages) and the MemoryPackages twin of the planner's tests."""

from __future__ import annotations

import os
import shlex
from collections.abc import Callable
from pathlib import Path

import pytest

from reconciler.adapters.apt import AptPackages
from reconciler.adapters.memory import MemoryPackages
from reconciler.base.errors import DependencyError
from reconciler.engine.execution.ports import Packages

PRESENT = "bash"  # dpkg lists it as installed on every Debian machine
ABSENT = "lpam-test-no-such-package"
FINDABLE_AFTER_UPDATE = "lpam-test-fresh-package"


def recording_apt_get(bin_dir: Path, calls: Path) -> None:
    """An `apt-get` that records each call; `install` of ABSENT fails as apt's does, and
    FINDABLE_AFTER_UPDATE is found only once `update` ran."""
    bin_dir.mkdir(exist_ok=True)
    script = bin_dir / "apt-get"
    script.write_text(f"""#!/usr/bin/env bash
echo "DEBIAN_FRONTEND=$DEBIAN_FRONTEND $*" >> {shlex.quote(str(calls))}
if [ "$1" = update ]; then touch {shlex.quote(str(calls))}.updated; exit 0; fi
for name in "$@"; do
  if [ "$name" = {ABSENT} ]; then echo "E: Unable to locate package $name"; exit 100; fi
  if [ "$name" = {FINDABLE_AFTER_UPDATE} ] && [ ! -e {shlex.quote(str(calls))}.updated ]; then
    echo "E: Unable to locate package $name"; exit 100
  fi
done
echo "Setting up $*"
""")
    script.chmod(0o755)


def calls_of(calls: Path) -> list[str]:
    return calls.read_text().splitlines() if calls.exists() else []


Factory = Callable[[Path, pytest.MonkeyPatch], tuple[Packages, Callable[[], list[str]]]]


def real(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Packages, Callable[[], list[str]]]:
    calls = tmp / "apt-calls"
    recording_apt_get(tmp / "bin", calls)
    monkeypatch.setenv("PATH", f"{tmp / 'bin'}{os.pathsep}{os.environ['PATH']}")
    return AptPackages(timeout=30), lambda: [c.split(" ", 1)[1] for c in calls_of(calls)]


def twin(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Packages, Callable[[], list[str]]]:
    packages = MemoryPackages(installed={PRESENT}, available={"x11-apps"},
                              after_update={FINDABLE_AFTER_UPDATE})
    return packages, lambda: [" ".join(c) for c in packages.calls]


@pytest.fixture(params=[real, twin], ids=["apt", "memory"])
def packages(request: pytest.FixtureRequest, tmp_path: Path,
             monkeypatch: pytest.MonkeyPatch) -> tuple[Packages, Callable[[], list[str]]]:
    factory: Factory = request.param
    return factory(tmp_path, monkeypatch)


def test_missing_lists_only_what_dpkg_does_not_have(
        packages: tuple[Packages, Callable[[], list[str]]]) -> None:
    port, _ = packages
    assert port.missing([PRESENT, ABSENT]) == [ABSENT]
    assert port.missing([PRESENT]) == []
    assert port.missing([]) == []


def test_nothing_runs_when_nothing_is_missing(
        packages: tuple[Packages, Callable[[], list[str]]]) -> None:
    port, calls = packages
    port.install([], log=lambda line: None)
    assert calls() == []


def test_a_package_apt_cannot_find_is_an_error_naming_it(
        packages: tuple[Packages, Callable[[], list[str]]]) -> None:
    port, calls = packages
    with pytest.raises(DependencyError, match=ABSENT):
        port.install([ABSENT], log=lambda line: None)
    assert [c.split()[0] for c in calls()] == ["install", "update", "install"]  # update once


def test_update_runs_only_when_a_package_was_not_found(
        packages: tuple[Packages, Callable[[], list[str]]]) -> None:
    port, calls = packages
    port.install([FINDABLE_AFTER_UPDATE], log=lambda line: None)
    recorded = calls()
    assert [c.split()[0] for c in recorded] == ["install", "update", "install"]


def test_real_install_is_one_non_interactive_batch_without_recommends(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    port, _ = real(tmp_path, monkeypatch)
    lines: list[str] = []
    port.install(["libfoo-dev", "x11-apps"], log=lines.append)
    assert calls_of(tmp_path / "apt-calls") == [
        "DEBIAN_FRONTEND=noninteractive install -y --no-install-recommends libfoo-dev x11-apps"]
    assert "Setting up install -y --no-install-recommends libfoo-dev x11-apps" in lines


def test_real_error_shows_apts_own_words(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    port, _ = real(tmp_path, monkeypatch)
    with pytest.raises(DependencyError) as caught:
        port.install(["x11-apps", ABSENT], log=lambda line: None)
    assert f"E: Unable to locate package {ABSENT}" in caught.value.message
    assert any(ABSENT in line for line in caught.value.details)
