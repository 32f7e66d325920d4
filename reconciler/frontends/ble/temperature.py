"""The CPU temperature the phone shows, and the unit it asked for.

The phone counts a car as connected while temperatures arrive: more than 20 s without one
and it shows "Disconnected". So the reading is a file read on the GATT loop itself (the
kernel's thermal zone, `Layout.thermal_zone`, millidegrees
Celsius), never behind anything that can wait on an apply.
"""

from __future__ import annotations

from pathlib import Path

from reconciler.core.privzone.temperature import DEFAULT_UNIT, Unit, parse_unit, temperature_text

UNREADABLE = "--"
"""What the phone shows when the kernel gives no temperature (a machine without a zone)."""


class Thermometer:
    """The CPU's temperature as bluezone formatted it; Fahrenheit until the phone writes
    `C` to the unit characteristic (bluezone's start)."""

    def __init__(self, zone: Path) -> None:
        self.zone = zone
        self.fahrenheit = DEFAULT_UNIT is Unit.FAHRENHEIT

    def reading(self) -> str:
        try:
            milli = int(self.zone.read_text(encoding="ascii").strip())
        except (OSError, ValueError):
            return UNREADABLE
        return temperature_text(milli, self.fahrenheit)

    def set_unit(self, value: bytes) -> None:
        """`C` or `F` as the phone writes them; anything else is ignored, as by bluezone."""
        found = parse_unit(value)
        if found is not None:
            self.fahrenheit = found is Unit.FAHRENHEIT
