"""The unit's last output shown beside a failure is a courtesy: the service manager failing
to give it is no error of its own, but a bug elsewhere must not pass for "no output"."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import pytest

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import MemoryScripts, MemoryStore
from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.errors import ServiceError
from reconciler.base.layout import Layout
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.supervision import log_tail
from schemas.record import StateRecord


class Failing(MemoryServices):
    def __init__(self, error: BaseException) -> None:
        super().__init__()
        self.error = error

    def logs(self, name: str, lines: int = 20) -> list[str]:
        raise self.error


def context(tmp_path: Path, services: MemoryServices) -> Context:
    layout = Layout(tmp_path)
    store = MemoryStore(layout=layout, remotes={})
    return Context(layout=layout, store=store, folders=DiskFolders(layout=layout, store=store),
                   scripts=MemoryScripts(runs_dir=layout.runs), services=services,
                   record=StateRecord(lineage="L"),
                   clock=lambda: datetime(2026, 11, 24, tzinfo=timezone.utc))


@pytest.mark.parametrize("error", [ServiceError("journalctl is not on PATH"),
                                   PermissionError(13, "Permission denied")])
def test_logs_the_manager_cannot_give_are_left_out(tmp_path: Path, error: Exception) -> None:
    assert log_tail(context(tmp_path, Failing(error)), "lpam-app-x") == []


def test_a_bug_while_reading_logs_raises(tmp_path: Path) -> None:
    with pytest.raises(KeyError):
        log_tail(context(tmp_path, Failing(KeyError("bug"))), "lpam-app-x")


def test_the_underlay_comes_from_the_context_the_caller_built(tmp_path: Path) -> None:
    """The engine never asks the machine for /opt/ros itself: the workflow gives the probe."""
    from reconciler.engine.execution.supervision import runtime
    from reconciler.engine.records.generations import Generation

    ctx = context(tmp_path, MemoryServices())
    ctx.underlay = lambda: Path("/opt/ros/noetic/setup.bash")
    gen = Generation(name="x", generation="g", launch="can_to_ros/vsl.launch")
    assert runtime(ctx, gen).ros_setup == Path("/opt/ros/noetic/setup.bash")
