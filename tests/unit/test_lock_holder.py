"""Who holds the apply lock, said as every command says it (issue 30 item 9): a script of
an apply that has ended is no apply in progress, and a plan made beside it says that it
fell back to what is local."""

from __future__ import annotations

import os
import subprocess

from reconciler.engine.execution.lock import Holding
from reconciler.workflow.planning import busy_note


def test_a_dead_apply_holding_the_lock_through_its_script_is_worded_as_apply_words_it(
) -> None:
    """Item 9: the lock's note names a pid that is gone and the script's process group:
    plan says what apply says — a script of an apply that has ended — and that it fell
    back to an offline plan."""
    gone = subprocess.Popen(["true"])
    gone.wait()  # a pid that was an lpam process and is gone now
    orphan = Holding.of(f"pid {gone.pid}: running alpha start.sh in process group 815")
    assert orphan.orphaned and not orphan.alive and orphan.group == "815"
    note = busy_note(orphan.note)
    assert "a script of an apply that has ended" in note and "still running" in note
    assert "an apply in progress" not in note
    assert "offline" in note and "nothing fetched" in note
    live = busy_note(f"pid {os.getpid()}: running alpha start.sh in process group 815")
    assert "an apply in progress (pid" in live and "offline" in live
