"""How long each use case waits for the apply lock: `--lock-timeout` when given, else the
use case's own default (workflow/defaults.py) — the fetches too, which once waited 60 s
whatever the operator said."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from reconciler.base.errors import LockError
from reconciler.base.layout import KEEP_GENERATIONS, Layout
from reconciler.engine.execution.lock import apply_lock
from reconciler.workflow.applying import ApplyOptions
from reconciler.workflow.defaults import FETCH_LOCK_TIMEOUT, LOCK_TIMEOUT
from reconciler.workflow.machine import Machine
from reconciler.workflow.sync import sync
from schemas.agent import AgentConfig


def test_each_lock_waits_its_own_default_unless_told() -> None:
    assert ApplyOptions().lock_wait() == LOCK_TIMEOUT == 10.0
    assert ApplyOptions().lock_wait(FETCH_LOCK_TIMEOUT) == FETCH_LOCK_TIMEOUT == 60.0
    assert ApplyOptions(lock_timeout=2.5).lock_wait(FETCH_LOCK_TIMEOUT) == 2.5
    assert ApplyOptions().keep_generations == KEEP_GENERATIONS == 3


def test_a_syncs_fetch_obeys_the_lock_timeout(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    config = AgentConfig.model_validate({
        "version": 1, "vehicle": "car1",
        "source": {"url": str(tmp_path / "nowhere.git"), "branch": "main"}})
    machine = Machine(layout)
    with apply_lock(layout, timeout=0):
        started = time.monotonic()
        with pytest.raises(LockError):
            sync(machine, config, report=lambda event: None,
                 options=ApplyOptions(lock_timeout=0.2))
        assert time.monotonic() - started < 5  # not the 60 s a fetch waits by default
