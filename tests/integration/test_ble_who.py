"""Who changed the car over Bluetooth (issue 31): the real `lpam ble` on a private
dbus-daemon, the bluetoothd double standing in for two phones — one BlueZ knows by name,
one it knows only by address — and the car's own history and status read back with the
real CLI.

What a car's owner checks after a day in a staging area: `lpam history` (its By column
and `--json`) and `lpam status` name the phone that made each change, with its name when
BlueZ has one; a write lpam refused is in the service's log with the phone's address.
"""

from __future__ import annotations

import json
from pathlib import Path

from tests.bluez_double import bond, until
from tests.integration.apps import FieldCar
from tests.integration.test_ble_service import (  # noqa: F401 - fixtures
    INPUT_UUID,
    PHONE_A,
    PHONE_B,
    ble,
    bus,
    car,
    phones,
    scenario,
)
from tests.privzone_client import Phone

PIXEL = "Pixel 7"  # the name BlueZ knows PHONE_A by; PHONE_B has none


def test_history_and_status_name_the_phone_that_made_each_change(
    car: FieldCar, bus: str,  # noqa: F811 - fixtures
) -> None:
    async def body() -> None:
        async with phones(bus) as double:
            bond(double, PHONE_A, PIXEL)
            a, b = Phone(double, PHONE_A), Phone(double, PHONE_B)
            await a.connect()
            await a.next_status(0, 10)
            await a.send("app_params", {"app": "ticker", "params": {"RATE": "5"}})
            assert await a.next_status(1, 60) == "App command success!"
            await b.send("app_params", {"app": "ticker", "params": {"RATE": "7"}})
            assert await a.next_status(2, 60) == "App command success!"
            await double.write(INPUT_UUID, b"[1, 2]", PHONE_B)  # refused by the bridge
            await double.write(INPUT_UUID, b"\x00", PHONE_B)
            said = await a.next_status(3, 10)
            assert said != "App command success!", said
            await until(lambda: "refused" in (car.root / "ble.log").read_text(), 10)
            await a.command("As")  # the phone's stop holds the app: status names the phone
            assert await a.next_status(4, 60) == "App command success!"

    with ble(car, bus):
        scenario(body)

    [hold] = car.lpam.status()["holds"]
    assert "was stopped by `lpam stop` (asked by phone AA:BB:CC:DD:EE:01 (Pixel 7))" in \
        hold["what"], hold

    entries = json.loads(car.lpam("history", "--json").stdout)
    assert [(e["params"], e["by"]) for e in entries[-2:]] == [
        ({"RATE": "5"}, {"kind": "phone", "id": "AA:BB:CC:DD:EE:01", "name": "Pixel 7"}),
        ({"RATE": "7"}, {"kind": "phone", "id": "AA:BB:CC:DD:EE:02"}),
    ]
    header, *rows = car.lpam("history").stdout.splitlines()
    at = header.index("By")
    assert [row[at:].split("  ")[0] for row in rows[-2:]] == [
        "phone AA:BB:CC:DD:EE:01 (Pixel 7)", "phone AA:BB:CC:DD:EE:02"]
    assert car.lpam.status()["last_apply"]["by"] == \
        {"kind": "phone", "id": "AA:BB:CC:DD:EE:02"}
    assert "(asked by phone AA:BB:CC:DD:EE:02)" in car.lpam("status").stdout
    log = Path(car.root / "ble.log").read_text()
    assert "request from phone AA:BB:CC:DD:EE:01 (Pixel 7): " in log, log
    assert "refused a write from AA:BB:CC:DD:EE:02" in log, log
