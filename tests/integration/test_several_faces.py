"""Every face shows every app (issue 22, item 5), end to end: the real `lpam` CLI, a real
git daemon and a real supervisord under the test's root running three apps at once from a
desired state of version 2 — a controller that owns the panda, a recorder and a tracker
that claim nothing.

What a user checks: `lpam status --json` lists the three, each running with its own pid;
`lpam stop recorder` stops the recorder's process and no other (the others' pids are the
same), and holds the recorder alone; `lpam start` starts it again; `lpam logs tracker`
shows the tracker's output and no other app's; `lpam logs` with no name shows every app's,
each line under its app's name; a name that is not installed is refused naming the three;
`lpam restart` with no name restarts all three.
The supervisord is stopped by its pid at the end (test_services.py's `lpam` fixture).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.test_services import alive, lpam  # noqa: F401  (the fixture)

NAMES = ("controller", "recorder", "tracker")

PROGRAM = """\
import time
print("{name} up", flush=True)
while True:
    print("{name} tick", flush=True)
    time.sleep(0.3)
"""

# A health window of 1 s, not the default 10 s: each apply, start and restart waits it out
# for every app, and what this file asserts (which app is operated, which pids change,
# what is shown) does not depend on its length.
CATALOG = """\
apps:
  - name: controller
    command: [python3, -u, main.py]
    health: {settle_seconds: 1}
    properties:
      - owns_panda: true
  - name: recorder
    command: [python3, -u, main.py]
    health: {settle_seconds: 1}
  - name: tracker
    command: [python3, -u, main.py]
    health: {settle_seconds: 1}
"""


@pytest.fixture
def repo(make_repo: Callable[[str], RepoBuilder]) -> RepoBuilder:
    builder = make_repo("apps.git")
    builder.write("libpanda-apps.yaml", CATALOG)
    for name in NAMES:
        builder.write(f"{name}/main.py", PROGRAM.format(name=name))
        builder.write(f"{name}/description.txt", f"the {name}\n")
    builder.commit("three apps that share nothing but the car")
    builder.push()
    return builder


def three_apps(url: str) -> str:
    return "\n".join(["version: 2", "repositories:", f"  - url: {url}", "apps:",
                      *(f"  - name: {n}" for n in NAMES)]) + "\n"


def installed(car: Lpam) -> dict[str, dict[str, Any]]:
    return {a["name"]: a for a in car.status()["installed"]}


def pids(car: Lpam) -> dict[str, int | None]:
    return {name: app["unit"]["pid"] for name, app in installed(car).items()}


def test_three_apps_each_operated_alone_and_each_shown(
    lpam: Lpam, repo: RepoBuilder, git_daemon: GitDaemon  # noqa: F811  (the fixture)
) -> None:
    lpam.desired(three_apps(git_daemon.url("apps.git")))
    done = lpam("apply", "--yes")
    assert done.returncode == 0, done.stderr
    shown = lpam.status()
    assert [a["name"] for a in shown["installed"]] == list(NAMES)
    assert shown["app"]["name"] == "controller"
    assert {n: a["claims"] for n, a in installed(lpam).items()} == {
        "controller": ["panda"], "recorder": [], "tracker": []}
    before = pids(lpam)
    assert all(isinstance(pid, int) and alive(pid) for pid in before.values()), before

    stopped = lpam("stop", "recorder")
    assert stopped.returncode == 0, stopped.stderr
    assert "Stopped recorder;" in stopped.stdout
    now = installed(lpam)
    assert now["recorder"]["unit"]["active"] == "inactive" and now["recorder"]["held"]
    assert not alive(int(str(before["recorder"])))
    assert {n: now[n]["unit"]["pid"] for n in ("controller", "tracker")} == {
        n: before[n] for n in ("controller", "tracker")}
    assert not now["controller"]["held"] and not now["tracker"]["held"]
    assert "stopped by operator" in lpam("status").stdout

    started = lpam("start")
    assert started.returncode == 0, started.stderr
    assert "Started recorder." in started.stdout
    assert "controller, tracker are already running." in started.stdout
    after = pids(lpam)
    assert isinstance(after["recorder"], int) and alive(after["recorder"])
    assert after["recorder"] != before["recorder"]
    assert {n: after[n] for n in ("controller", "tracker")} == {
        n: before[n] for n in ("controller", "tracker")}

    deadline = time.monotonic() + 10
    logs = lpam("logs", "tracker", "-n", "5")
    while "tracker tick" not in logs.stdout and time.monotonic() < deadline:
        time.sleep(0.2)
        logs = lpam("logs", "tracker", "-n", "5")
    assert logs.returncode == 0, logs.stderr
    assert "tracker tick" in logs.stdout
    assert "controller" not in logs.stdout and "recorder" not in logs.stdout
    every = lpam("logs", "-n", "3")
    assert every.returncode == 0, every.stderr
    assert {line.split(" | ")[0] for line in every.stdout.splitlines()} == set(NAMES)
    assert all(line.startswith(f"{line.split(' | ')[0]} | {line.split(' | ')[0]} ")
               for line in every.stdout.splitlines())
    unknown = lpam("logs", "recordr")
    assert unknown.returncode != 0 and "controller, recorder, tracker" in unknown.stderr
    assert lpam("plan", "--detailed-exitcode").returncode == 0

    again = lpam("restart")  # no name: every installed app, each its own process
    assert again.returncode == 0, again.stderr
    assert "Restarted controller, recorder, tracker." in again.stdout
    restarted = pids(lpam)
    assert all(isinstance(pid, int) and alive(pid) for pid in restarted.values()), restarted
    assert all(restarted[n] != after[n] and not alive(int(str(after[n]))) for n in NAMES)
