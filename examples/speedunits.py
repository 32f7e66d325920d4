"""Speed unit conversions, a dependency the demo's apps get through pip."""

KMH_PER_MPH = 1.609344


def to_unit(kmh: float, unit: str) -> float:
    """`kmh` in `unit` (km/h or mph)."""
    return kmh / KMH_PER_MPH if unit == "mph" else kmh
