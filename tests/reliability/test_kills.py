"""Kill `lpam apply` at random instants and check the vehicle afterwards.

The apps here behave like the field's: `start.sh` leaves a daemon behind that holds the
CAN bus — modelled by an exclusive `flock` on `$LPAM_ROOT/bus.lock` — and `stop.sh` ends
it. A daemon that finds the bus taken writes to `collisions.log`: two apps on the bus.
Each round changes the desired app (or its parameters), starts a real `lpam apply`, and
at a random instant sends it SIGKILL (lpam alone: its script goes on, as after an OOM
kill) or SIGINT (Ctrl-C); then a plain apply must succeed and leave exactly the desired
app's daemon on the bus, and a plan must be empty.

The normal run tries a few instants; `LPAM_CRASH_INSTANTS=240` tries many (the figures
in docs/reliability.md come from such a run). The seed is fixed, so a failure replays.
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, desired
from tests.lengths import knob

INSTANTS = knob("LPAM_CRASH_INSTANTS", 6, 240)  # LPAM_LONG=1: 240 (tests/lengths.py)

START = """\
sleep "0.$((RANDOM % 4))"
pidfile="$LPAM_ROOT/daemons/$LPAM_APP.pid"
mkdir -p "$LPAM_ROOT/daemons"
( if flock -n 9; then exec sleep 600; else echo "$LPAM_APP" >> "$LPAM_ROOT/collisions.log"; fi
) 9>>"$LPAM_ROOT/bus.lock" </dev/null >/dev/null 2>&1 &
echo $! > "$pidfile"
"""

STOP = """\
pidfile="$LPAM_ROOT/daemons/$LPAM_APP.pid"
if [ -f "$pidfile" ]; then
  pid=$(cat "$pidfile")
  kill "$pid" 2>/dev/null
  for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.05; done
  rm -f "$pidfile"
fi
sleep "0.$((RANDOM % 3))"
"""

SLOW = 'sleep "0.$((RANDOM % 5))"\n'


def field_like_repo(builder: RepoBuilder) -> None:
    builder.write("libpanda-apps.yaml", "apps:\n  - name: alpha\n  - name: beta\n")
    for app in ("alpha", "beta"):
        for script, body in (("start", START), ("stop", STOP), ("install", SLOW),
                             ("uninstall", SLOW)):
            builder.write(f"{app}/{script}.sh", f"#!/usr/bin/env bash\n{body}", executable=True)
    builder.commit("apps that hold the bus")
    builder.push()


def before_lpam(err: str, sig: signal.Signals) -> bool:
    """A Ctrl-C that landed while Python itself was starting (importing `site`, before any
    of lpam's code ran): Python prints that traceback, and no program can prevent it."""
    return sig is signal.SIGINT and "/reconciler/" not in err and "KeyboardInterrupt" in err


def daemons(root: Path) -> dict[str, int]:
    """App → pid of its daemon, for the daemons still alive."""
    alive = {}
    for pidfile in (root / "daemons").glob("*.pid"):
        try:
            pid = int(pidfile.read_text())
            os.kill(pid, 0)
        except (ValueError, OSError):
            continue
        alive[pidfile.stem] = pid
    return alive


@pytest.fixture
def root(tmp_path: Path) -> Iterator[Path]:
    root = tmp_path / "root"
    yield root
    for pidfile in (root / "daemons").glob("*.pid"):  # stop every daemon the apps started
        with contextlib.suppress(ValueError, OSError):
            os.kill(int(pidfile.read_text()), signal.SIGKILL)


def test_random_kills_never_put_two_apps_on_the_bus(
    root: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    field_like_repo(make_repo("apps.git"))
    url = git_daemon.url("apps.git")
    lpam = Lpam(root)
    rng = random.Random(5)
    killed = 0
    for round_ in range(INSTANTS):
        app = rng.choice(["alpha", "beta"])
        lpam.desired(desired(url, app, RUN=str(round_ % 3)))
        proc = lpam.spawn("apply", "--yes", "--lock-timeout", "60")
        time.sleep(rng.uniform(0.0, 2.0))
        sig = rng.choice([signal.SIGKILL, signal.SIGINT])
        if proc.poll() is None:
            os.kill(proc.pid, sig)
            killed += 1
        _, err = proc.communicate(timeout=120)
        assert "internal error" not in err, err
        assert "Traceback" not in err or before_lpam(err, sig), err
        done = lpam("apply", "--yes", "--lock-timeout", "60")
        assert done.returncode == 0, f"round {round_} ({sig.name}): {done.stderr}"
        collisions = root / "collisions.log"
        assert not collisions.exists(), f"round {round_}: {collisions.read_text()}"
        assert set(daemons(root)) == {app}, f"round {round_}: {daemons(root)}"
        assert lpam("plan", "--detailed-exitcode").returncode == 0
    assert killed > 0
    print(f"\n{INSTANTS} rounds, {killed} applies killed mid-way, 0 collisions")
