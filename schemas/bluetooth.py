"""Who may change the car over Bluetooth, and what the running `lpam ble` says of itself
(`<root>/run/lpam/ble.json`, written when it starts serving, removed when it stops).

Why a file: `lpam status` is another process and must say which mode the car's Bluetooth
service is in; `/run` is a tmpfs on a car, so the file means nothing after a reboot, and
its `pid` lets status tell a running service from one that was killed. Version 1.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictStr

from schemas.enums import StrEnum


class Writes(StrEnum):
    """Who may write the characteristics that change the car (`lpam ble --writes`)."""

    BONDED = "bonded"
    """Only a phone bonded with the car (paired through `lpam ble pair`): the default."""
    OPEN = "open"
    """Any phone in range, as libpanda's bluezone allowed: for a lab."""


class BleService(BaseModel):
    """The running `lpam ble`: its write mode, its adapter and its process."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[1] = 1
    writes: Writes = Field(description="who may change the car: bonded phones, or any")
    adapter: StrictStr = Field(description="the BlueZ adapter it serves on")
    pid: int = Field(ge=1, description="the `lpam ble` process")
    since: StrictStr = Field(description="when it started serving (ISO 8601)")
