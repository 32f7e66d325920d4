"""What `lpam status` learns of the running `lpam ble` (engine/records/bluetooth.py): the
mode while its process runs; nothing once it was killed, or from a file it cannot read."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from reconciler.base.layout import Layout
from reconciler.engine.records.bluetooth import clear_service, read_service, record_service
from schemas.bluetooth import BleService, Writes


def service(pid: int, writes: Writes = Writes.BONDED) -> BleService:
    return BleService(writes=writes, adapter="/org/bluez/hci0", pid=pid,
                      since="2026-11-27T20:00:00+00:00")


def test_the_running_service_is_read_and_only_its_writer_clears_it(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    assert read_service(layout) is None  # lpam ble never ran here
    record_service(layout, service(os.getpid(), Writes.OPEN))
    assert read_service(layout) == service(os.getpid(), Writes.OPEN)
    clear_service(layout, os.getpid() + 1)  # an older lpam ble ending: not its file
    assert read_service(layout) is not None
    clear_service(layout, os.getpid())
    assert read_service(layout) is None and not layout.ble_service.exists()


def test_a_killed_service_or_a_damaged_file_says_nothing(tmp_path: Path) -> None:
    layout = Layout(tmp_path)
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    record_service(layout, service(int(gone.stdout)))
    assert read_service(layout) is None  # its process is gone: no mode to tell
    assert read_service(layout, living=False) is not None
    layout.ble_service.write_text("{not json")
    assert read_service(layout) is None
