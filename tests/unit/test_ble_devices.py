"""The phone behind a write as lpam names it (reconciler/adapters/bluez/devices.py): the
address from BlueZ's device path, and a name only when the phone really has one."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.adapters.bluez.devices import Device, address_in, device_of
from reconciler.adapters.bluez.shape import Characteristic
from reconciler.base.layout import Layout
from reconciler.frontends.ble.bridge import Bridge
from reconciler.frontends.ble.temperature import Thermometer
from reconciler.frontends.console import debug_log
from reconciler.workflow.machine import Machine
from schemas.record import Actor

PATH = "/org/bluez/hci0/dev_aa_BB_cc_DD_ee_0F"


def test_the_path_spells_the_address() -> None:
    assert address_in(PATH) == "AA:BB:CC:DD:EE:0F"
    assert address_in("/org/bluez/hci0") is None and address_in(None) is None
    assert address_in("/org/bluez/hci0/dev_AA_BB/extra") is None


@pytest.mark.parametrize(("props", "found"), [
    ({"Address": "AA:BB:CC:DD:EE:0F", "Name": "Pixel 7", "Alias": "Lab phone"},
     Device("AA:BB:CC:DD:EE:0F", "Lab phone")),  # the name a user gave it first
    ({"Address": "AA:BB:CC:DD:EE:0F", "Name": "Pixel 7"}, Device("AA:BB:CC:DD:EE:0F", "Pixel 7")),
    # BlueZ's Alias of a phone with no name is its address: no name
    ({"Address": "AA:BB:CC:DD:EE:0F", "Alias": "AA-BB-CC-DD-EE-0F"},
     Device("AA:BB:CC:DD:EE:0F", None)),
    (None, Device("AA:BB:CC:DD:EE:0F", None)),  # BlueZ did not answer: the path's address
])
def test_the_device_properties_name_the_phone(props: dict[str, str] | None,
                                              found: Device) -> None:
    assert device_of(PATH, props) == found


def test_a_fault_naming_the_phone_costs_its_name_not_the_request(tmp_path: Path) -> None:
    """Asking BlueZ who wrote is lpam's own code on the bridge's worker: a bug there must
    not end the worker (every later request would go unanswered). The request runs as
    the address the device path spells, and the fault is logged."""
    from reconciler.frontends.ble import answers

    lines: list[str] = []
    machine = Machine.at(Layout(tmp_path))
    asked: list[Actor] = []

    def broken(device: str | None) -> Actor:
        raise RuntimeError("a bug")

    def answer(work: object, by: Actor) -> answers.Answer:
        asked.append(by)
        return answers.Answer(status="done")

    bridge = Bridge(machine, lambda char, value: None,
                    thermometer=Thermometer(machine.layout.thermal_zone),
                    log=lines.append, bug=lambda: debug_log(machine.layout), who=broken)
    bridge._answer = answer  # type: ignore[method-assign]
    bridge.write(Characteristic.COMMAND, b"A", PATH)
    bridge.write(Characteristic.COMMAND, b"A", PATH)
    assert bridge.stop(10)
    assert asked == [Actor(kind="phone", id="AA:BB:CC:DD:EE:0F")] * 2  # both answered
    assert any(line.startswith(f"internal error naming the phone at {PATH}: ")
               for line in lines), lines
    assert "request from phone AA:BB:CC:DD:EE:0F: <Command.INFO: 'A'>" in lines
