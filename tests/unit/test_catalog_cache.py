"""Parsed catalogs kept beside their checkout (engine/records/catalogs.py): a hit is what
parsing gives, a miss or a bad cache file parses, a bad catalog is never kept."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError
from reconciler.core.documents import parse_catalog
from reconciler.engine.records import catalogs

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "reference" / \
    "libpanda-default-apps.libpanda-apps.yaml"
WILD = b"""\
apps:
  - name: alpha
    path: alpha/
    properties:
      - owns_panda: true
    dependencies:
      - apt: can-utils
    ros_repositories:
      - owner: jmscslgroup
        repo: can_to_ros
        branch_or_hash: d7134708e49001b407aba4c382c9c6daec6ce0de
  - name: beta
    path: apps/beta
"""
LABEL = Path("apps@0123456789ab/libpanda-apps.yaml")


def checkout(tmp_path: Path) -> Path:
    (tmp_path / "repo" / ".git").mkdir(parents=True)
    return tmp_path / "repo"


def kept(where: Path) -> list[Path]:
    return sorted((where / ".git").glob(f"{catalogs.PREFIX}*.json"))


def texts() -> list[bytes]:
    found = [WILD, b"apps:\n  - name: one\n    path: one\n"]
    return found + ([REAL.read_bytes()] if REAL.exists() else [])


@pytest.mark.parametrize("data", texts())
def test_a_second_read_is_the_first_parse_without_parsing(
    tmp_path: Path, data: bytes, monkeypatch: pytest.MonkeyPatch,
) -> None:
    where = checkout(tmp_path)
    first = catalogs.parsed(where, LABEL, data)
    assert first == parse_catalog(LABEL, data.decode()) and len(kept(where)) == 1

    def parses(*_: object) -> None:
        raise AssertionError("parsed again")

    monkeypatch.setattr(catalogs, "parse_catalog", parses)
    assert catalogs.parsed(where, LABEL, data) == first


def test_a_catalog_that_does_not_parse_is_never_kept(tmp_path: Path) -> None:
    where = checkout(tmp_path)
    for _ in range(2):
        with pytest.raises(ConfigError) as caught:
            catalogs.parsed(where, LABEL, b"apps:\n  - name: one\n    bogus: 1\n")
        assert caught.value.line == 3
    assert kept(where) == []


def test_a_damaged_cache_file_is_parsed_again_and_rewritten(tmp_path: Path) -> None:
    where = checkout(tmp_path)
    good = catalogs.parsed(where, LABEL, WILD)
    (file,) = kept(where)
    file.write_text('{"apps": [{"name": "intruder"')  # cut short
    assert catalogs.parsed(where, LABEL, WILD) == good
    assert catalogs.parsed(where, LABEL, WILD).app("alpha") is not None


def test_another_lpam_or_another_text_is_another_entry(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    where = checkout(tmp_path)
    catalogs.parsed(where, LABEL, WILD)
    monkeypatch.setattr(catalogs, "__version__", "99.0")
    catalogs.parsed(where, LABEL, WILD)
    catalogs.parsed(where, LABEL, WILD + b"  - name: gamma\n")
    assert len(kept(where)) == 3


def test_without_a_checkout_nothing_is_written(tmp_path: Path) -> None:
    assert catalogs.parsed(tmp_path / "absent", LABEL, WILD).app("beta") is not None
    assert not (tmp_path / "absent").exists()
