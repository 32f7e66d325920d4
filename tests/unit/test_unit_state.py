"""The systemctl show parser against fixtures of each output shape systemd produces."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.unit import UnitState
from reconciler.engine.observe.unit_state import parse_properties, parse_show

FIXTURES = Path(__file__).parent.parent / "fixtures" / "systemctl"

EXPECTED = {
    "running": UnitState("app", known=True, active="active", sub="running", pid=1342),
    "failed-start-limit": UnitState("app", known=True, active="failed", sub="failed",
                                    restarts=5),
    "inactive-dead": UnitState("app", known=True, active="inactive", sub="dead"),
    "not-found": UnitState("app", known=False),
    "activating-auto-restart": UnitState("app", known=True, active="activating",
                                         sub="auto-restart", restarts=2),
    "old-systemd-no-nrestarts": UnitState("app", known=True, active="active", sub="running",
                                          pid=977),
    "reordered": UnitState("app", known=True, active="active", sub="running", restarts=3,
                           pid=2211),
    "extra-properties": UnitState("app", known=True, active="active", sub="reload",
                                  restarts=1, pid=2211),
    "not-found-still-running": UnitState("app", known=False),
    "masked": UnitState("app", known=True, active="inactive", sub="dead"),
    "unexpected-active-state": UnitState("app", known=True, active="unknown", sub="cleaning"),
}


def test_every_fixture_has_an_expectation() -> None:
    assert {p.stem for p in FIXTURES.glob("*.txt")} == set(EXPECTED)


@pytest.mark.parametrize("fixture", sorted(EXPECTED))
def test_parse_show(fixture: str) -> None:
    state = parse_show("app", (FIXTURES / f"{fixture}.txt").read_text())
    assert state == EXPECTED[fixture]


def test_running_means_known_and_active() -> None:
    states = {name: parse_show("app", (FIXTURES / f"{name}.txt").read_text())
              for name in EXPECTED}
    assert {name for name, s in states.items() if s.running} == {
        "running", "old-systemd-no-nrestarts", "reordered", "extra-properties"}
    assert states["not-found"].describe() == "unit app unknown to this service manager"
    assert states["activating-auto-restart"].describe() == "unit app activating (auto-restart)"


def test_values_keep_their_equals_signs() -> None:
    props = parse_properties((FIXTURES / "extra-properties.txt").read_text())
    assert props["Description"] == "lpam app demo (p=a=b)"
    assert props["UID"] == "[not set]"


@pytest.mark.parametrize("text", ["", "garbage\n", "ActiveState=active\nSubState=running\n"])
def test_output_without_load_state_is_not_an_unknown_unit(text: str) -> None:
    with pytest.raises(ValueError, match="LoadState"):
        parse_show("app", text)


@pytest.mark.parametrize("value", ["", "[not set]", "-1", "²", "12a"])
def test_odd_counts_read_as_none(value: str) -> None:
    state = parse_show("app", f"LoadState=loaded\nActiveState=active\nNRestarts={value}\n"
                              f"MainPID={value}\n")
    assert (state.restarts, state.pid) == (0, None)
