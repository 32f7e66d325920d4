"""The field's frontends on a car that runs several apps (issue 22, item 5), end to end:
the real `libpanda-app-manager` on a real LPAM_ROOT, the app repository served by a real
`git daemon`, the apps under a real supervisord, and the phone's `app_info` made by the
Bluetooth service's own answer function on the same root.

What a field engineer checks: `-d` (and the phone's list) says `yes` under Enabled for
every installed app, and bluezone reads it; `-c` names each; `-i` of a second panda owner
replaces the first one only, the app beside it keeping its very process; `-i` of an app
that claims nothing runs it beside the others; `-u` stops them all.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from reconciler.base.process import alive
from reconciler.workflow.machine import Machine
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import TICKER
from tests.integration.test_shim import HEADER, Shim, bluezone_rows, gone

OWNER = "    properties:\n      - owns_panda: true\n"
CATALOG = "apps:\n" + "".join(
    f"  - name: {name}\n    command: [python3, -u, run.py]\n"
    f"    health: {{settle_seconds: 0.5}}\n{OWNER if name in ('driver', 'pilot') else ''}"
    for name in ("driver", "pilot", "ticker", "tocker"))


def several(port: int) -> str:
    """A version-2 desired state: a panda owner beside an app that claims nothing."""
    return f"""\
# The car's apps, side by side.
version: 2
mirrors:
  "https://github.com/": "git://127.0.0.1:{port}/"
repositories:
  - repo: fleet/apps
    ref: main
apps:
  - name: driver    # drives the car
  # the logger of every drive
  - name: ticker
    params: {{RATE: "5"}}
# end of file
"""


@pytest.fixture
def car(tmp_path: Path, git_daemon: GitDaemon, make_repo: Callable[[str], RepoBuilder]
        ) -> Iterator[Shim]:
    apps = make_repo("fleet/apps")
    apps.write("libpanda-apps.yaml", CATALOG)
    for name in ("driver", "pilot", "ticker", "tocker"):
        apps.write(f"{name}/run.py", TICKER)
        apps.write(f"{name}/description.txt", f"the {name}\n")
    apps.commit("two panda owners, two apps that claim nothing")
    apps.push()
    shim = Shim(tmp_path / "root")
    shim.desired.parent.mkdir(parents=True)
    shim.desired.write_text(several(git_daemon.port))
    try:
        done = shim.lpam("apply", "--yes")
        assert done.returncode == 0, done.stderr
        yield shim
    finally:
        shutdown(Layout(shim.root))  # this root's supervisord, by its pid


def pids(shim: Shim) -> dict[str, int]:
    """Each app's last started process (the app writes `NAME PID` when it starts)."""
    found: dict[str, int] = {}
    for line in (shim.root / "starts").read_text().splitlines():
        name, pid = line.split()
        found[name] = int(pid)
    return found


def enabled(shim: Shim) -> list[tuple[str, str, str]]:
    """(app, enabled, running) of each row of `-d`, as bluezone reads them."""
    out = shim.ok("-d")
    assert out.split("\n")[0] == HEADER
    return [(r["app"], r["enabled"], r["running"]) for r in bluezone_rows(out.encode())]


def phone_rows(shim: Shim) -> list[tuple[str, str, str]]:
    """(app, enabled, running) of the phone's `app_info` message, joined and decoded."""
    from reconciler.frontends.ble.answers import app_info

    body = json.loads(b"".join(app_info(Machine.at(Layout(shim.root)))).rstrip(b"\0"))
    assert body["type"] == "app_info"
    return [(r["app"], r["enabled"], r["running"]) for r in json.loads(body["contents"])]


def test_every_installed_app_is_enabled_in_the_table_and_on_the_phone(car: Shim) -> None:
    table = [("driver", "yes", "yes"), ("pilot", "no", "no"), ("ticker", "yes", "yes"),
             ("tocker", "no", "no")]
    assert enabled(car) == table
    assert phone_rows(car) == table
    assert car.ok("-c") == "driver\nticker\n"
    assert car.ok("-t") == "driver: unit lpam-app-driver active (running)\n" \
        "ticker: unit lpam-app-ticker active (running)\n"
    assert car.ok("-l") == "driver pilot ticker tocker\n"


def test_i_replaces_the_panda_owner_only_and_adds_an_app_that_claims_nothing(car: Shim
                                                                           ) -> None:
    before = pids(car)
    text = car.desired.read_text()
    car.ok("-i", "pilot")
    assert gone(before["driver"])
    assert alive(before["ticker"]) and pids(car)["ticker"] == before["ticker"]  # untouched
    pilot = pids(car)["pilot"]
    assert alive(pilot)
    assert car.desired.read_text() == text.replace("driver  ", "pilot   ")  # comments kept
    assert enabled(car) == [("driver", "no", "no"), ("pilot", "yes", "yes"),
                            ("ticker", "yes", "yes"), ("tocker", "no", "no")]
    assert car.ok("-c") == "ticker\npilot\n"  # in the order they were installed

    car.ok("-i", "tocker")  # claims nothing: it runs beside the others
    assert car.desired.read_text().endswith(
        '  - name: ticker\n    params: {RATE: "5"}\n  - name: tocker\n# end of file\n')
    now = pids(car)
    assert (now["ticker"], now["pilot"]) == (before["ticker"], pilot)
    assert all(alive(now[name]) for name in ("pilot", "ticker", "tocker"))
    assert [row[1] for row in enabled(car)] == ["no", "yes", "yes", "yes"]

    unchanged = car.desired.read_bytes()
    car.ok("-i", "ticker")  # already listed: nothing changes
    assert car.desired.read_bytes() == unchanged

    car.ok("-u")  # no app: every app stops
    assert "\napps: []\n" in car.desired.read_text()
    assert all(gone(pid) for pid in pids(car).values())
    assert car.ok("-c") == "None\n"
    assert [row[1] for row in enabled(car)] == ["no"] * 4
