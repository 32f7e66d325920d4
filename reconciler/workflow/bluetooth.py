"""The use cases of the car's Bluetooth service beside serving the phone (frontends/ble/):
saying who may change the car while `lpam ble` runs, the pairing window, and the bonded
phones.

Who may change the car is one setting, `Writes`, given to `lpam ble --writes` (the
default: bonded phones only) and, on a car, written into `lpam-ble.service` by
`lpam install-ble --writes` — no other file holds it. The running service records it
(engine/records/bluetooth.py) so that `lpam status` can say it.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from reconciler.base.layout import Layout
from reconciler.engine.records.bluetooth import clear_service, record_service
from schemas.bluetooth import BleService, Writes

if TYPE_CHECKING:
    from reconciler.adapters.bluez.pairing import Phone

# Imported inside functions: BlueZ pairing (dbus_fast: an optional dependency present on a car)
# loads only for `lpam ble pair/phones/forget` (start-up).


@contextlib.contextmanager
def announced(layout: Layout, *, writes: Writes, adapter: str, since: str) -> Iterator[None]:
    """While the block runs, `lpam status` says this process serves on `adapter` in the
    mode `writes`."""
    pid = os.getpid()
    record_service(layout, BleService(writes=writes, adapter=adapter, pid=pid, since=since))
    try:
        yield
    finally:
        clear_service(layout, pid)


def said(writes: Writes) -> str:
    """The service's log line about who may change the car."""
    if writes is Writes.OPEN:
        return ("writes are OPEN (--writes open): any phone in range may change the car's "
                "apps, as with bluezone")
    return ("only a bonded phone may change the car's apps; `lpam ble pair` opens a "
            "pairing window")


def pair(*, bus_address: str | None, adapter: str, seconds: int,
         stopped: Callable[[], bool], opened: Callable[[], None],
         paired: Callable[[str], None]) -> None:
    """`lpam ble pair`: the adapter pairable and discoverable for `seconds` (or until
    `stopped()`), with an agent that accepts each pairing (adapters/bluez/pairing.py);
    `opened` is told once the window is open, `paired` each phone that paired in it."""
    from reconciler.adapters.bluez.pairing import window

    asyncio.run(window(bus_address=bus_address, adapter=adapter, seconds=seconds,
                       stopped=stopped, opened=opened, paired=paired))


def bonded_phones(*, bus_address: str | None, adapter: str) -> list[Phone]:
    """`lpam ble phones`: the phones paired or bonded with the car, by address."""
    from reconciler.adapters.bluez.pairing import phones

    return asyncio.run(phones(bus_address=bus_address, adapter=adapter))


def forget_phone(*, bus_address: str | None, adapter: str, address: str) -> Phone:
    """`lpam ble forget ADDRESS`: the phone's bond removed; the phone that was."""
    from reconciler.adapters.bluez.pairing import check_address, forget

    wanted = check_address(address)  # before any bus: a typo is said as such
    return asyncio.run(forget(bus_address=bus_address, adapter=adapter, address=wanted))
