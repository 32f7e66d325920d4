"""The use cases of the car's Bluetooth service beside serving the phone (frontends/ble/):
saying who may change the car while `lpam ble` runs, the pairing window, and the bonded
phones.

Who may change the car is one setting, `Writes`, given to `lpam ble --writes` (the
default: bonded phones only) and, on a car, written into `lpam-ble.service` by
`lpam install-ble --writes` — no other file holds it. The running service records it
(engine/records/bluetooth.py) so that `lpam status` can say it.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from reconciler.base.layout import Layout
from reconciler.engine.records.bluetooth import clear_service, record_service
from schemas.bluetooth import BleService, Writes


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
