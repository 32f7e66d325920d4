"""`lpam sync` and `lpam agent` wait for closed gates as agent.yaml says unless told
otherwise, and `lpam install-agent` refuses settings it cannot read: rules of the
workflow (workflow/agent.py), whoever calls it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.workflow import agent
from reconciler.workflow.agent import Agent, install_agent, one_pass, settings
from reconciler.workflow.applying import ApplyOptions
from reconciler.workflow.events import Event
from reconciler.workflow.machine import Machine
from reconciler.workflow.sync import Synced

SETTINGS = ("version: 1\nvehicle: car1\ngate_wait_seconds: 42\n"
            "source: {url: 'https://example.org/fleet.git', branch: main}\n")


def quiet(event: Event) -> None:
    pass


def test_a_pass_waits_as_the_settings_say_unless_told(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    layout = Layout(tmp_path)
    layout.agent_config.parent.mkdir(parents=True)
    layout.agent_config.write_text(SETTINGS)
    waits: list[float] = []

    def passed(machine: Machine, config: Any, *, options: ApplyOptions,
               **more: Any) -> Synced:
        waits.append(options.wait)
        return Synced("nothing to do", None)

    monkeypatch.setattr(agent, "sync", passed)
    machine = Machine(layout)
    config = settings(layout, None)
    one_pass(machine, config, options=ApplyOptions(), wait=None, report=quiet)
    one_pass(machine, config, options=ApplyOptions(), wait=3.0, report=quiet)
    assert Agent.following(machine, config, options=ApplyOptions(),
                           report=quiet).run(once=True) == 0
    assert waits == [42.0, 3.0, 42.0]


def test_install_agent_refuses_settings_it_cannot_read(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    bad = tmp_path / "agent.yaml"
    bad.write_text("version: 1\n")
    with pytest.raises(ConfigError):
        install_agent(Machine(layout), ["lpam"], config_file=bad, report=quiet)
    assert not layout.systemd_units.exists()
