"""Bad input for scriptless apps and health checks: refused at the document, located at
file:line:column, with the app named — before anything on the machine is touched."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError
from reconciler.core.documents import load_desired, parse_catalog

CATALOG = Path("lab@0123abcd/libpanda-apps.yaml")


@pytest.mark.parametrize(("entry", "expected", "line"), [
    ("command: python3 app.py", "valid list", 3),
    ("command: []", "must list a program", 3),
    ('command: [python3, ""]', "command[1] is empty", 3),
    ("command: [/usr/bin/python3]", "a program on PATH or a path inside the app folder", 3),
    ("command: [../escape.sh]", "inside the app folder", 3),
    ("command: [-rf]", "not an option", 3),
    ("launch: ../pkg/x.launch", "PACKAGE/FILE.launch", 3),
    ("launch: pkg/sub/x.launch", "PACKAGE/FILE.launch", 3),
    ("launch: pkg/x.py", "PACKAGE/FILE.launch", 3),
    ("health: {command: [-x]}", "health.command[0]", 3),
    ("health: {settle_seconds: -1}", "greater than or equal to 0", 3),
    ("health: {timeout_seconds: 0}", "greater than 0", 3),
    ("health: {retries: 3}", "retries", 3),
])
def test_bad_scriptless_entries_are_located(entry: str, expected: str, line: int) -> None:
    text = f"apps:\n  - name: speedlog\n    {entry}\n"
    with pytest.raises(ConfigError) as info:
        parse_catalog(CATALOG, text)
    assert expected in info.value.message
    assert info.value.line == line and info.value.path == CATALOG


def test_command_and_launch_together_are_refused() -> None:
    text = "apps:\n  - name: x\n    command: [a]\n    launch: p/x.launch\n"
    with pytest.raises(ConfigError, match="either `command:` or `launch:`") as info:
        parse_catalog(CATALOG, text)
    assert info.value.line == 4


def test_a_good_scriptless_entry_reads_back() -> None:
    text = ("apps:\n  - name: speedlog\n    command: [python3, -u, speedlog.py, --rate, '10']\n"
            "    health: {settle_seconds: 5, command: [./healthy.sh], timeout_seconds: 10}\n"
            "  - name: vsl\n    launch: can_to_ros/vsl.launch\n")
    catalog = parse_catalog(CATALOG, text)
    speedlog, vsl = catalog.apps
    assert speedlog.command == ["python3", "-u", "speedlog.py", "--rate", "10"]
    assert speedlog.health is not None and speedlog.health.command == ["./healthy.sh"]
    assert vsl.launch == "can_to_ros/vsl.launch" and vsl.command is None


@pytest.mark.parametrize(("app", "expected"), [
    ("{name: x, user: Root}", "is not a user name"),
    ("{name: x, user: 'a b'}", "is not a user name"),
    ("{name: x, health: {settle_seconds: soon}}", "valid number"),
])
def test_bad_app_settings_in_the_desired_state_are_located(
    tmp_path: Path, app: str, expected: str
) -> None:
    path = tmp_path / "desired.yaml"
    path.write_text(f"version: 1\napp: {app}\n")
    with pytest.raises(ConfigError) as info:
        load_desired(path)
    assert expected in info.value.message and info.value.line == 2


def test_the_desired_health_overrides_the_catalogs_field_by_field() -> None:
    from schemas.service import Health

    catalog = Health(settle_seconds=5, command=["./healthy.sh"])
    desired = Health(settle_seconds=0)
    merged = desired.over(catalog)
    assert merged.settle_seconds == 0 and merged.command == ["./healthy.sh"]
