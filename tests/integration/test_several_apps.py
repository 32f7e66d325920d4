"""Issue 22's car: a panda-owning controller, a recorder and a tracker at once, as real
processes under the root's supervisord, driven by the real CLI (tests/integration/several.py).
Switching the controller touches neither other app's process; a second panda owner in the
desired state is refused before anything changes; a failed health check of one new app
rolls the whole apply back."""

from __future__ import annotations

import json
from pathlib import Path

from tests.integration.apps import Lpam
from tests.integration.several import car_url, collisions, lpam, running, several

__all__ = ["car_url", "lpam"]  # fixtures


def started(root: Path) -> list[str]:
    """Every start the recorder and the tracker made: `APP PID` lines."""
    log = root / "starts"
    return log.read_text().splitlines() if log.exists() else []


def applied(lpam: Lpam, text: str) -> None:
    lpam.desired(text)
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr


def test_switching_the_controller_touches_neither_the_recorder_nor_the_tracker(
        lpam: Lpam, car_url: str) -> None:
    applied(lpam, several(car_url, "ctl-a", "recorder", "tracker"))
    before = running(lpam.root)
    assert sorted(before) == ["ctl-a", "recorder", "tracker"]
    assert all(len(pids) == 1 for pids in before.values()), before
    starts = started(lpam.root)

    lpam.desired(several(car_url, "ctl-b", "recorder", "tracker"))
    plan = lpam("plan")
    assert plan.returncode == 0, plan.stderr
    assert "recorder" not in "".join(line for line in plan.stdout.splitlines()
                                     if line.lstrip().startswith(("~", "+", "-", "±")))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr

    after = running(lpam.root)
    assert sorted(after) == ["ctl-b", "recorder", "tracker"]
    assert (after["recorder"], after["tracker"]) == (before["recorder"], before["tracker"])
    assert started(lpam.root) == starts  # neither was started again
    assert collisions(lpam.root) == []
    record = json.loads((lpam.root / "var/lib/lpam/state.json").read_text())
    assert [(a["name"], a["status"]) for a in record["apps"]] == [
        ("recorder", "running"), ("tracker", "running"), ("ctl-b", "running")]
    assert lpam("plan", "--detailed-exitcode").returncode == 0


def test_a_second_panda_owner_is_refused_before_anything_changes(lpam: Lpam,
                                                                  car_url: str) -> None:
    applied(lpam, several(car_url, "ctl-a", "recorder"))
    state = lpam.root / "var/lib/lpam/state.json"
    record, before = state.read_bytes(), running(lpam.root)

    path = lpam.desired(several(car_url, "ctl-a", "recorder", "ctl-b"))
    for command in (("plan",), ("apply", "--yes")):
        done = lpam(*command)
        assert done.returncode != 0
        assert f"{path}:7:5" in done.stderr, done.stderr
        assert "ctl-b claims the exclusive resource panda" in done.stderr
        assert "ctl-a" in done.stderr and "Traceback" not in done.stderr
    assert state.read_bytes() == record
    assert running(lpam.root) == before


def test_a_failed_health_check_of_one_new_app_rolls_the_whole_apply_back(
        lpam: Lpam, car_url: str) -> None:
    applied(lpam, several(car_url, "ctl-a", "recorder", "tracker"))
    before = running(lpam.root)

    lpam.desired(several(car_url, "ctl-b", "recorder", "bad-tracker"))
    done = lpam("apply", "--yes")
    assert done.returncode == 3, done.stderr  # a health failure
    assert "bad-tracker: its health check `./healthy.sh` failed" in done.stderr
    assert "Rolled back to ctl-a, recorder, tracker." in done.stderr

    after = running(lpam.root)
    assert sorted(after) == ["ctl-a", "recorder", "tracker"]
    assert after["recorder"] == before["recorder"]  # the apply never touched it
    assert collisions(lpam.root) == []
    record = json.loads((lpam.root / "var/lib/lpam/state.json").read_text())
    assert sorted((a["name"], a["status"]) for a in record["apps"]) == [
        ("ctl-a", "running"), ("recorder", "running"), ("tracker", "running")]
    assert record["last_apply"]["result"] == "rolled back"
    rolled = {h["app"] for h in record["history"] if h["result"] == "rolled back"}
    assert rolled == {"ctl-b", "bad-tracker"}


def test_rollback_brings_the_previous_set_back_and_history_shows_sets(lpam: Lpam,
                                                                      car_url: str) -> None:
    applied(lpam, several(car_url, "ctl-a", "recorder", "tracker"))
    first = running(lpam.root)
    applied(lpam, several(car_url, "ctl-b", "recorder"))
    assert sorted(running(lpam.root)) == ["ctl-b", "recorder"]

    shown = lpam("history")
    assert shown.returncode == 0, shown.stderr
    header, rows = shown.stdout.strip().split("\n", 1)
    assert header.split()[:3] == ["Now", "Time", "App"]  # a table with its header
    blocks = [b.splitlines() for b in rows.split("\n\n")]
    assert [sorted(line.lstrip("* ").split()[1] for line in b) for b in blocks] == [
        ["ctl-a", "recorder", "tracker"], ["ctl-b", "recorder"]]
    assert all(line.startswith("*") for line in blocks[1])  # the set installed now

    back = lpam("rollback", "--yes")
    assert back.returncode == 0, back.stderr
    assert "Rolled back to" in back.stdout and "They hold" in back.stdout
    now = running(lpam.root)
    assert sorted(now) == ["ctl-a", "recorder", "tracker"]
    assert now["recorder"] == first["recorder"]  # it was in both sets: untouched
    assert collisions(lpam.root) == []
    assert lpam("plan", "--detailed-exitcode").returncode == 0  # held: nothing proposed
