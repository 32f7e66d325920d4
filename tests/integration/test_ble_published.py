"""What a fleet car publishes names who made its last change (issue 31): the agent with
the fleet's revision, then the phone that switched the app over Bluetooth.

End to end: a car following a fleet repository served by a real `git daemon`, the real
`lpam sync` publishing to `status/<vehicle>`, the real `lpam ble` on a private
dbus-daemon with the bluetoothd double as the phone, and `lpam fleet status` in a clone —
what the lab reads to learn who put an app on a car.
"""

from __future__ import annotations

import json
import subprocess
from typing import Any

from tests.bluez_double import bond
from tests.gitserver import RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.test_ble_service import (  # noqa: F401 - the bus fixture
    PHONE_A,
    ble,
    bus,
    phones,
    scenario,
)
from tests.integration.test_ble_who import PIXEL
from tests.privzone_client import Phone


def published(fleet: RepoBuilder) -> dict[str, Any]:
    shown = subprocess.run(["git", "show", "status/rav4-07:status.json"], cwd=fleet.bare,
                           capture_output=True, text=True, timeout=30, check=True)
    found: dict[str, Any] = json.loads(shown.stdout)
    return found


def test_the_published_status_names_who_made_the_last_change(
    car: Lpam, fleet: RepoBuilder, bus: str,  # noqa: F811 - fixtures
) -> None:
    assert car("sync").returncode == 0
    first = published(fleet)["last_change"]
    assert first["apps"][0].startswith("alpha@") and first["by"] == \
        {"kind": "agent", "id": fleet.rev("HEAD")}

    async def body() -> None:
        async with phones(bus) as double:
            bond(double, PHONE_A, PIXEL)
            phone = Phone(double, PHONE_A)
            await phone.connect()
            await phone.next_status(0, 10)
            await phone.send("app_enable", {"app": "beta"})
            assert await phone.next_status(1, 60) == "App command success!"

    with ble(car, bus):
        scenario(body)
    assert car("sync").returncode == 0  # the override holds; the status goes out
    body_ = published(fleet)
    assert body_["version"] == 3 and body_["app"]["name"] == "beta"
    assert body_["last_change"]["apps"][0].startswith("beta@")
    assert body_["last_change"]["by"] == \
        {"kind": "phone", "id": "AA:BB:CC:DD:EE:01", "name": "Pixel 7"}
    clone = car.root.parent / "clone"
    subprocess.run(["git", "clone", "-q", "--mirror", str(fleet.bare), str(clone)],
                   check=True, timeout=60)
    shown = car("fleet", "status", "--repo", str(clone))
    assert shown.returncode == 0, shown.stderr
    assert "phone AA:BB:CC:DD:EE:01 (Pixel 7)" in shown.stdout, shown.stdout
