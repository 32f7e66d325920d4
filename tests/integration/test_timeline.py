"""The timeline (issue 33) as a car writes it: real apps under the root's supervisord,
driven by the real CLI, switched, stopped by an operator, crashed and restarted by their
service manager; the edges `lpam provenance` reads are checked against what the test did."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

from tests.integration.apps import Lpam
from tests.integration.several import car_url, lpam, running, several

__all__ = ["car_url", "lpam"]  # fixtures


def edges(root: Path) -> list[dict[str, object]]:
    path = root / "var/lib/lpam/timeline/timeline.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()]


def said(root: Path) -> list[tuple[object, ...]]:
    """(kind, how, app) of every edge but clock edges, in order."""
    return [(e["kind"], e["how"], e.get("app")) for e in edges(root) if e["kind"] != "clock"]


def applied(lpam: Lpam, text: str) -> None:
    lpam.desired(text)
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr


def test_switches_and_an_operator_stop_are_edges_with_what_ran(lpam: Lpam, car_url: str
                                                               ) -> None:
    applied(lpam, several(car_url, "ctl-a", "recorder"))
    applied(lpam, several(car_url, "ctl-b", "recorder"))
    stop = lpam("stop", "ctl-b")
    assert stop.returncode == 0, stop.stderr
    assert said(lpam.root) == [
        ("began", "apply", "ctl-a"), ("began", "apply", "recorder"),
        ("ended", "apply", "ctl-a"), ("began", "apply", "ctl-b"),
        ("ended", "operator", "ctl-b")]
    first = edges(lpam.root)[0]
    software = json.loads((lpam.root / "var/lib/lpam/timeline/software" /
                           f"{first['software']}.json").read_text())
    record = json.loads((lpam.root / "var/lib/lpam/state.json").read_text())
    commit = record["repositories"][0]["commit"]
    assert (software["app"], software["commit"]) == ("ctl-a", commit)
    # the app is told its provenance, and the file it names says the same
    pid = running(lpam.root)["recorder"][0]
    env = dict(item.split("=", 1) for item in
               Path(f"/proc/{pid}/environ").read_text().split("\0") if "=" in item)
    assert env["LPAM_COMMIT"] == commit
    told = json.loads(Path(env["LPAM_PROVENANCE"]).read_text())
    assert (told["app"], told["generation"], told["params_digest"]) == (
        "recorder", env["LPAM_GENERATION"], env["LPAM_PARAMS_DIGEST"])


def test_a_crash_the_manager_restarts_is_seen_at_the_next_look(lpam: Lpam, car_url: str
                                                               ) -> None:
    applied(lpam, several(car_url, "recorder"))
    assert lpam("status").returncode == 0  # the first look notes the unit's pid
    [pid] = running(lpam.root)["recorder"]
    os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        now = running(lpam.root).get("recorder", [])
        if now and now != [pid]:
            break
        time.sleep(0.2)
    assert lpam("status").returncode == 0
    assert said(lpam.root)[-1] == ("restarted", "crashed", "recorder")
