"""A car of several apps, for the tests of issue 22: two controllers that own the panda
(each holds the bus as tests/integration/test_fault_truth.py's apps do, an exclusive
`flock`, and a copy that finds it taken writes `collisions.log`: two owners), a recorder
and a tracker that claim nothing and record each start in `$LPAM_ROOT/starts`, and a
tracker whose health check fails.
All run as real processes under the root's supervisord (scriptless apps); the `lpam`
fixture stops them and the supervisord by pid at the end."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import TICKER, processes
from tests.integration.test_fault_truth import BUS, lpam

CATALOG = """\
apps:
  - name: ctl-a
    command: [python3, -u, bus.py]
    health: {settle_seconds: 1}
    properties:
      - owns_panda: true
  - name: ctl-b
    command: [python3, -u, bus.py]
    health: {settle_seconds: 1}
    properties:
      - owns_panda: true
  - name: recorder
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0.5}
  - name: tracker
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0.5}
  - name: bad-tracker
    command: [python3, -u, ticker.py]
    health: {settle_seconds: 0.5, command: [./healthy.sh]}
"""


def several(url: str, *apps: str) -> str:
    """A desired state version 2 of these apps, each at its own line."""
    lines = ["version: 2", "repositories:", f"  - url: {url}", "apps:"]
    lines += [f"  - name: {app}" for app in apps]
    return "\n".join(lines) + "\n"


@pytest.fixture
def car_url(make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon) -> str:
    builder = make_repo("car.git")
    builder.write("libpanda-apps.yaml", CATALOG)
    for app in ("ctl-a", "ctl-b"):
        builder.write(f"{app}/bus.py", BUS)
    for app in ("recorder", "tracker", "bad-tracker"):
        builder.write(f"{app}/ticker.py", TICKER)
    builder.write("bad-tracker/healthy.sh", "#!/bin/sh\necho 'no GPS fix'\nexit 1\n",
                  executable=True)
    builder.commit("a controller pair, a recorder and trackers")
    builder.push()
    return git_daemon.url("car.git")


def app_of(pid: int) -> str:
    """The app a process runs as (its LPAM_APP)."""
    env = (Path("/proc") / str(pid) / "environ").read_bytes().split(b"\0")
    return next(e.split(b"=", 1)[1].decode() for e in env if e.startswith(b"LPAM_APP="))


def running(root: Path) -> dict[str, list[int]]:
    """App name → the pids of its live copies."""
    found: dict[str, list[int]] = {}
    for pid in processes(root):
        with contextlib.suppress(OSError, StopIteration):
            found.setdefault(app_of(pid), []).append(pid)
    return found


def collisions(root: Path) -> list[str]:
    log = root / "collisions.log"
    return log.read_text().splitlines() if log.exists() else []


__all__ = ["car_url", "lpam"]  # fixtures
