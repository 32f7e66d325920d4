"""Which boot this is and how long ago it began: the clock a Pi cannot get wrong.

A Pi has no real-time clock. Until GPS (libpanda's pandaSetSystemTime) or NTP sets it, its
wall clock is the last shutdown's, often hours behind; then it jumps. Every moment lpam
writes into the timeline (schemas/timeline.py) is therefore taken three ways: the kernel's
boot id (new at every boot), CLOCK_BOOTTIME (seconds since that boot, counting suspend,
never set by anyone) and the wall clock. Within one boot, wall - boottime changes only
when the clock is set, which is how a later moment corrects an earlier one.
"""

from __future__ import annotations

import time
from pathlib import Path

BOOT_ID = Path("/proc/sys/kernel/random/boot_id")
UNKNOWN_BOOT = "unknown-boot"


def boot_id(path: Path = BOOT_ID) -> str:
    """This boot's id; a machine without one (not Linux) is one boot for lpam's lifetime
    of the process, and says so in the name."""
    try:
        return path.read_text(encoding="ascii").strip()[:64] or UNKNOWN_BOOT
    except (OSError, UnicodeDecodeError):
        return UNKNOWN_BOOT


def boottime() -> float:
    """Seconds since this boot (CLOCK_BOOTTIME where the system has it)."""
    clock = getattr(time, "CLOCK_BOOTTIME", time.CLOCK_MONOTONIC)
    return time.clock_gettime(clock)

