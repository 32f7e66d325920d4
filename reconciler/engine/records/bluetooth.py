"""The running `lpam ble`'s word about itself (`<root>/run/lpam/ble.json`, schemas/bluetooth.py):
written when it starts serving, removed when it stops, read by `lpam status`.

Reading never fails: a file whose process is gone (a `lpam ble` killed, SIGKILL leaves no
chance to remove it) or that cannot be parsed says nothing about the car now, so it reads
as no service at all. Only the process that wrote the file removes it, so a `lpam ble`
that ends never erases the word of one started after it.
"""

from __future__ import annotations

import contextlib

from pydantic import ValidationError

from reconciler.base.atomic import write_atomic
from reconciler.base.layout import Layout
from reconciler.base.process import alive
from schemas.bluetooth import BleService

MAX_BYTES = 4096


def record_service(layout: Layout, service: BleService) -> None:
    write_atomic(layout.ble_service, service.model_dump_json(indent=2) + "\n")


def clear_service(layout: Layout, pid: int) -> None:
    """Remove the file if the process `pid` wrote it."""
    found = read_service(layout, living=False)
    if found is not None and found.pid == pid:
        with contextlib.suppress(FileNotFoundError):
            layout.ble_service.unlink()


def read_service(layout: Layout, *, living: bool = True) -> BleService | None:
    """The running `lpam ble` (with `living`: only while its process runs), or None."""
    try:
        with layout.ble_service.open("rb") as file:
            service = BleService.model_validate_json(file.read(MAX_BYTES))
    except (OSError, ValueError, ValidationError):
        return None
    return service if not living or alive(service.pid) else None
