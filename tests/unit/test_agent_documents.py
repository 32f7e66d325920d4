"""agent.yaml refused at file:line:column like every lpam document, and the joining of a
desired state's relative URLs onto the fleet repository's."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError, VersionError
from reconciler.core.documents import load_agent
from reconciler.workflow.sync import join_url


def test_a_good_agent_yaml_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "agent.yaml"
    path.write_text("version: 1  # the fleet\nsource: {url: 'https://github.com/lab/fleet'}\n"
                    "vehicle_file: /etc/libpanda.d/vin\ninterval_seconds: 60\n")
    config = load_agent(path)
    assert (config.source.url, config.source.branch) == ("https://github.com/lab/fleet", "main")
    assert (config.vehicle, config.vehicle_file) == (None, "/etc/libpanda.d/vin")
    assert config.heartbeat_seconds == 6 * 3600  # hours, not minutes, unless set


def test_the_heartbeat_is_a_setting(tmp_path: Path) -> None:
    path = tmp_path / "agent.yaml"
    path.write_text("version: 1\nsource: {url: 'https://h/f'}\nheartbeat_seconds: 3600\n")
    assert load_agent(path).heartbeat_seconds == 3600


@pytest.mark.parametrize(("body", "expected", "line"), [
    ("source: {url: 'https://h/f'}\nvehicle: 'rav4 07'", "vehicle id 'rav4 07'", 3),
    ("source: {url: 'https://h/f'}\nvehicle: ../etc", "vehicle id", 3),
    ("source: {url: 'https://h/f', branch: '-x'}", "not a valid branch", 2),
    ("source: {url: 'https://h/f'}\nvehicle_file: vin", "absolute path", 3),
    ("source: {url: 'https://h/f'}\nvehicle: a\nvehicle_file: /vin", "not both", 4),
    ("source: {url: 'https://h/f'}\ninterval_seconds: 1", "greater than or equal to 10", 3),
    ("source: {url: 'https://h/f'}\nintervall: 60", "unknown key 'intervall'", 3),
    ("vehicle: a", "source is required", 1),
    ("source: {url: 'https://h/f'}\nheartbeat_seconds: 60", "greater than or equal to 300", 3),
    ("source: {url: 'https://h/f'}\nheartbeat_seconds: 1e9", "less than or equal to 604800",
     3),
    ("source: {url: 'https://h/f'}\nheartbeat_seconds: six", "a valid number", 3),
    ("source: {url: 'https://h/f'}\ninterval_seconds: 3600\nheartbeat_seconds: 600",
     "shorter than interval_seconds", 4),
])
def test_bad_agent_yaml_is_located(tmp_path: Path, body: str, expected: str, line: int) -> None:
    path = tmp_path / "agent.yaml"
    path.write_text(f"version: 1\n{body}\n")
    with pytest.raises(ConfigError) as info:
        load_agent(path)
    assert expected in info.value.message and info.value.line == line
    assert info.value.path == path


def test_an_agent_yaml_from_a_newer_lpam_says_so(tmp_path: Path) -> None:
    path = tmp_path / "agent.yaml"
    path.write_text("version: 2\nsource: {url: 'https://h/f'}\n")
    with pytest.raises(VersionError):
        load_agent(path)


@pytest.mark.parametrize(("base", "relative", "joined"), [
    ("git://192.168.4.1/fleet.git", "../apps.git", "git://192.168.4.1/apps.git"),
    ("https://github.com/lab/fleet", "../apps", "https://github.com/lab/apps"),
    ("https://github.com/lab/fleet", "../../other/apps", "https://github.com/other/apps"),
    ("/srv/git/fleet.git", "../apps.git", "/srv/git/apps.git"),
])
def test_relative_urls_join_the_fleet_repositorys_like_submodules(
        base: str, relative: str, joined: str) -> None:
    assert join_url(base, relative) == joined
