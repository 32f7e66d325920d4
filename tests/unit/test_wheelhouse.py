"""The offline installer's check (scripts/wheelhouse.py): a folder the car cannot install
lpam from is never called complete.

The download itself needs the package registry, which tests never reach; it was run by
hand and its result is in the README. What is tested here is what decides "complete":
which wheels load on the car, and the closure of lpam's requirements with the *car's*
markers, which pip on another Python gets wrong (it evaluates `python_version < "3.10"`
for itself)."""

from __future__ import annotations

import importlib.util
import sys
import zipfile
from pathlib import Path
from types import ModuleType

import pytest

CAR = ((3, 9), (2, 31), "aarch64")


@pytest.fixture(scope="module")
def wheelhouse() -> ModuleType:
    path = Path(__file__).resolve().parents[2] / "scripts" / "wheelhouse.py"
    spec = importlib.util.spec_from_file_location("wheelhouse", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["wheelhouse"] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(("name", "fits"), [
    ("pydantic-2.13.5-py3-none-any.whl", True),
    ("supervisor-4.3.0-py2.py3-none-any.whl", True),
    ("pydantic_core-2.46.5-cp39-cp39-manylinux_2_17_aarch64.manylinux2014_aarch64.whl", True),
    ("dulwich-0.24.10-cp39-cp39-manylinux_2_28_aarch64.whl", True),  # glibc 2.28 <= 2.31
    ("x-1.0-cp37-abi3-manylinux2014_aarch64.whl", True),  # stable ABI of an older CPython
    ("x-1.0-cp39-cp39-manylinux_2_34_aarch64.whl", False),  # needs a newer glibc than Bullseye
    ("x-1.0-cp39-cp39-manylinux2014_x86_64.whl", False),  # this machine's, not the car's
    ("x-1.0-cp311-cp311-manylinux2014_aarch64.whl", False),  # another Python
    ("x-1.0-cp311-abi3-manylinux2014_aarch64.whl", False),  # stable ABI of a newer CPython
    ("x-1.0-cp39-cp39-linux_aarch64.whl", False),  # not manylinux: built for another distro
    ("x-1.0.tar.gz", False),
])
def test_only_wheels_the_car_loads_count(wheelhouse: ModuleType, name: str, fits: bool) -> None:
    assert wheelhouse.installs_on(name, *CAR) is fits


def _wheel(folder: Path, name: str, version: str, *requires: str) -> None:
    stem = name.replace("-", "_")  # a wheel's file name spells `-` as `_`
    info = f"{stem}-{version}.dist-info"
    lines = ["Metadata-Version: 2.1", f"Name: {name}", f"Version: {version}",
             *(f"Requires-Dist: {r}" for r in requires)]
    with zipfile.ZipFile(folder / f"{stem}-{version}-py3-none-any.whl", "w") as archive:
        archive.writestr(f"{info}/METADATA", "\n".join(lines) + "\n")


def test_the_closure_uses_the_cars_markers_not_this_pythons(
        wheelhouse: ModuleType, tmp_path: Path) -> None:
    _wheel(tmp_path, "lpam", "0.1.0", "pydantic>=2.7", "eval_type_backport>=0.2; "
           'python_version < "3.10"', "hostonly; python_version >= \"3.12\"",
           'armonly; platform_machine == "aarch64"', "tools; extra == \"test\"")
    _wheel(tmp_path, "pydantic", "2.13.5", "typing_extensions>=4.6")
    _wheel(tmp_path, "typing_extensions", "4.16.0")
    car = wheelhouse.environment((3, 9), "aarch64")
    assert wheelhouse.missing(tmp_path, "lpam", car) == ["armonly", "eval_type_backport>=0.2"]
    newer = wheelhouse.environment((3, 12), "x86_64")
    assert wheelhouse.missing(tmp_path, "lpam", newer) == ["hostonly"]

    _wheel(tmp_path, "eval_type_backport", "0.1.0")  # too old for the requirement
    assert "eval_type_backport>=0.2" in wheelhouse.missing(tmp_path, "lpam", car)
    _wheel(tmp_path, "eval_type_backport", "0.4.0")
    (tmp_path / "eval_type_backport-0.1.0-py3-none-any.whl").unlink()
    _wheel(tmp_path, "armonly", "1.0")
    assert wheelhouse.missing(tmp_path, "lpam", car) == []


def test_a_dependency_of_a_dependency_is_followed(wheelhouse: ModuleType, tmp_path: Path) -> None:
    _wheel(tmp_path, "lpam", "0.1.0", "python-can>=4.3")
    _wheel(tmp_path, "python-can", "4.6.1", "wrapt~=1.10", 'pywin32; sys_platform == "win32"')
    car = wheelhouse.environment((3, 9), "aarch64")
    assert wheelhouse.missing(tmp_path, "lpam", car) == ["wrapt~=1.10"]


def test_a_folder_with_a_source_distribution_is_incomplete(
        wheelhouse: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _wheel(tmp_path, "lpam", "0.1.0")
    (tmp_path / "wrapt-1.17.3.tar.gz").write_bytes(b"")
    assert wheelhouse.check(tmp_path, *CAR) is False
    assert "wrapt-1.17.3.tar.gz: not a wheel" in capsys.readouterr().err


def test_a_legacy_manylinux_tag_is_judged_by_its_glibc(wheelhouse: ModuleType) -> None:
    wheel = "x-1.0-cp39-cp39-manylinux2014_aarch64.whl"  # manylinux2014 is glibc 2.17
    assert wheelhouse.installs_on(wheel, (3, 9), (2, 17), "aarch64") is True
    assert wheelhouse.installs_on(wheel, (3, 9), (2, 12), "aarch64") is False
