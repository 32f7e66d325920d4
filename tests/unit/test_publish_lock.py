"""The car's status push writes the store (a ref of the fleet repository) and so is made
under the apply lock, as every write to the store is: a write a kill cuts off leaves a lock
file (NAME.lock) that only the lock's holder may sweep (reconciler/adapters/git.py
`_stale_locks`). A push that cannot have the lock in time is not made this pass, says why,
and is offered again next pass; the car keeps working."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.layout import Layout
from reconciler.engine.execution.lock import apply_lock, holder
from reconciler.engine.records.state import read_agent_status, write_record
from reconciler.workflow import sync
from reconciler.workflow.events import Event, Note
from reconciler.workflow.machine import Machine
from schemas.agent import AgentConfig, AgentStatus, Source
from schemas.record import StateRecord

CONFIG = AgentConfig(version=1, source=Source(url="git://127.0.0.1:9/fleet.git"),
                     vehicle="rav4-07")


@pytest.fixture
def machine(tmp_path: Path) -> Machine:
    layout = Layout(tmp_path / "root")
    write_record(layout, StateRecord())
    layout.agent_status.parent.mkdir(parents=True, exist_ok=True)
    layout.agent_status.write_text(AgentStatus(vehicle="rav4-07").model_dump_json())
    return Machine(layout, given_services=MemoryServices())


def test_the_status_push_is_made_holding_the_apply_lock(
        machine: Machine, monkeypatch: pytest.MonkeyPatch) -> None:
    held: list[tuple[str, str | None]] = []
    monkeypatch.setattr(sync, "_push", lambda m, config, branch, *a, **k: held.append(
        (branch, holder(m.layout))))
    sync.publish(machine, CONFIG, report=lambda event: None)
    # the status and the timeline (issue 33), in one push; what another lpam waiting for
    # the lock is told
    assert len(held) == 1 and held[0][0] == "status/rav4-07"
    assert str(held[0][1]).endswith(": publishing this car's status")
    published = read_agent_status(machine.layout)
    assert published is not None and published.publication is not None
    assert published.publication.result == "pushed"


def test_a_push_that_cannot_have_the_lock_waits_for_the_next_pass(
        machine: Machine, monkeypatch: pytest.MonkeyPatch) -> None:
    pushed: list[str] = []
    monkeypatch.setattr(sync, "_push", lambda *a, **k: pushed.append("pushed"))
    monkeypatch.setattr(sync, "LOCK_TIMEOUT", 0.2)
    said: list[Event] = []
    with apply_lock(machine.layout, timeout=1):  # an apply under way
        sync.publish(machine, CONFIG, report=said.append)
    assert pushed == []
    published = read_agent_status(machine.layout)
    assert published is not None and published.publication is not None
    assert published.publication.result == "failed"
    notes = [e.text for e in said if isinstance(e, Note)]
    assert any("status not published" in n and "next pass" in n for n in notes), notes
