"""SIGKILL at random instants of a controller switch on a car of several apps.

The car (tests/integration/several.py) runs a panda-owning controller, a recorder and a
tracker under supervisord. Each round switches the controller (ctl-a ↔ ctl-b), starts a
real `lpam apply`, and at a random instant kills its whole session with SIGKILL (lpam and
whatever step it ran). Meanwhile the panda's owners are counted every 50 ms. Then a plain
apply must converge. Never, in any sample or afterwards:
- two processes own the panda (a copy that finds it taken also writes `collisions.log`);
- the recorder or the tracker is restarted (a switch of the controller is none of theirs);
- the timeline (issue 33) says otherwise: after each round `lpam provenance --at now`
  names exactly the generations the state record runs, and the bystanders began once.

The normal run tries a few rounds; `LPAM_SEVERAL_ROUNDS=200` tries many (the figures in
docs/reliability.md come from such a run). The seed is fixed, so a failure replays.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import signal
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

from tests.integration.apps import Lpam
from tests.integration.several import car_url, collisions, lpam, running, several
from tests.lengths import knob

__all__ = ["car_url", "lpam"]  # fixtures

ROUNDS = knob("LPAM_SEVERAL_ROUNDS", 4, 120)  # LPAM_LONG=1: 120 (tests/lengths.py)


class Owners(threading.Thread):
    """Samples the car every 50 ms: the controllers alive (two: two owners of the
    panda) and the pids of the recorder and the tracker (another pid: restarted)."""

    def __init__(self, root: Path) -> None:
        super().__init__(daemon=True)
        self.root = root
        self.samples = 0
        self.violations: list[str] = []
        self.others: set[tuple[str, int]] = set()
        self.done = threading.Event()

    def run(self) -> None:
        while not self.done.wait(0.05):
            apps = running(self.root)
            controllers = [(a, p) for a in ("ctl-a", "ctl-b") for p in apps.get(a, [])]
            if len(controllers) > 1:
                self.violations.append(f"two owners of the panda: {controllers}")
            self.others |= {(a, p) for a in ("recorder", "tracker") for p in apps.get(a, [])}
            self.samples += 1


def said_running(lpam: Lpam) -> set[tuple[str, str]]:
    """What `lpam provenance` says runs now (the timeline, after a look)."""
    now = datetime.now(timezone.utc).isoformat()
    done = lpam("provenance", "--at", now, "--json")
    assert done.returncode == 0, done.stderr
    return {(r["app"], r["generation"]) for r in json.loads(done.stdout)[0]["ran"]}


def truly_running(root: Path) -> set[tuple[str, str]]:
    record = json.loads((root / "var/lib/lpam/state.json").read_text())
    return {(a["name"], a["generation"]) for a in record["apps"] if a["status"] == "running"}


def test_sigkill_at_random_instants_of_a_switch_never_gives_the_panda_two_owners(
        lpam: Lpam, car_url: str) -> None:
    lpam.desired(several(car_url, "ctl-a", "recorder", "tracker"))
    assert lpam("apply", "--yes").returncode == 0
    owners = Owners(lpam.root)
    owners.start()
    chance = random.Random(22)
    mid_way = 0
    try:
        for number in range(ROUNDS):
            controller = "ctl-b" if number % 2 == 0 else "ctl-a"
            lpam.desired(several(car_url, controller, "recorder", "tracker"))
            apply = lpam.spawn("apply", "--yes")
            time.sleep(chance.uniform(0.0, 3.0))
            if apply.poll() is None:
                mid_way += 1
            with contextlib.suppress(ProcessLookupError):
                os.killpg(apply.pid, signal.SIGKILL)
            apply.communicate(timeout=60)
            done = lpam("apply", "--yes")
            assert done.returncode == 0, done.stderr
            assert sorted(running(lpam.root)) == [controller, "recorder", "tracker"]
            assert said_running(lpam) == truly_running(lpam.root)  # the timeline agrees
    finally:
        owners.done.set()
        owners.join(timeout=5)
    assert owners.violations == []
    assert collisions(lpam.root) == []
    assert len({a for a, _ in owners.others}) == 2 and len(owners.others) == 2, owners.others
    assert lpam("plan", "--detailed-exitcode").returncode == 0
    # neither bystander ever began or ended again on the timeline (issue 33)
    edges = [json.loads(line) for line in
             (lpam.root / "var/lib/lpam/timeline/timeline.jsonl").read_text().splitlines()]
    for app in ("recorder", "tracker"):
        assert [e["kind"] for e in edges if e.get("app") == app] == ["began"], app
    print(f"\n{ROUNDS} rounds, {mid_way} killed mid-apply, {owners.samples} samples, "
          f"{len(owners.violations)} violations")
