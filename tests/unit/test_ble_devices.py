"""The phone behind a write as lpam names it (reconciler/adapters/bluez/devices.py): the
address from BlueZ's device path, and a name only when the phone really has one."""

from __future__ import annotations

import pytest

from reconciler.adapters.bluez.devices import Device, address_in, device_of

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
