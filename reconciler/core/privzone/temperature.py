"""The thermometer the phone watches: the CPU's temperature, every second, in C or F.

The phone shows the link as lost after 20 seconds without a temperature notification, so
this characteristic is the link's heartbeat as much as a reading. bluezone read gpiozero's
`CPUTemperature` (the thermal zone's millidegrees divided by 1000), converted to Fahrenheit
unless the unit characteristic said `C`, and sent `str(round(t, 1)) + " " + unit`: "48.3 C",
"118.9 F", "50.0 C". The same text is built here from the millidegrees the adapter reads.
"""

from __future__ import annotations

from schemas.enums import StrEnum


class Unit(StrEnum):
    """The unit characteristic's value."""

    CELSIUS = "C"
    FAHRENHEIT = "F"


DEFAULT_UNIT = Unit.FAHRENHEIT  # bluezone started in Fahrenheit


def temperature_text(millidegrees: int, fahrenheit: bool) -> str:
    """bluezone's text for a thermal zone's reading (millidegrees Celsius)."""
    temperature = millidegrees / 1000
    unit = Unit.CELSIUS
    if fahrenheit:
        temperature = temperature * 1.8 + 32
        unit = Unit.FAHRENHEIT
    return f"{round(temperature, 1)} {unit}"


def parse_unit(data: bytes) -> Unit | None:
    """A write to the unit characteristic: its first byte, `C` or `F` in either case, as
    bluezone read it; anything else changes nothing (None), as it did there."""
    first = data[:1].decode("ascii", "replace").upper()
    return Unit(first) if first in ("C", "F") else None


def unit_value(unit: Unit) -> bytes:
    """The unit characteristic's value when the phone reads it."""
    return unit.value.encode("ascii")
