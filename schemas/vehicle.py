"""The vehicle's signals and the update gates of a desired state (both optional).

```yaml
vehicle:
  source: {follow: /etc/libpanda.d/currentCan.csv}   # the default; or {log: drive.log},
          # or {bus: {interface: socketcand, host: 127.0.0.1, port: 29536, channel: can0}}
  speed: {id: 0xB4, start_bit: 47, length: 16, byte_order: big_endian, scale: 0.01}
         # the default (the RAV4's SPEED); or {dbc: toyota.dbc, message: SPEED, signal: SPEED}
  stale_seconds: 10            # a source silent this long is "no signal"
gates:                         # opt-in: without it nothing is gated
  stationary_seconds: 60       # the speed at 0 this long: a stop at a light is not parked
  on_no_signal: defer          # or allow
  windows: ["22:00-06:00"]     # local times of day when a cutover may happen
  locks: [/run/lpam/locks/recording.lock, {path: /var/lib/lpam/locks/exp.lock, persistent: true}]
```

While an app runs it owns the panda (USB, exclusive), so lpam reads the speed from the
recording the app keeps writing, by default; a CAN HAT (socketcan) or a socketcand server
can be read directly. A signal is defined as a DBC line writes it (schemas/signal.py);
`vehicle.signal` decodes it, and adapters/can/dbc.py reads one out of a DBC file. Gates are
checked at the boundary between preparation and cutover (reconciler/adapters/gate.py).
"""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    StrictInt,
    StrictStr,
    field_validator,
    model_serializer,
    model_validator,
)

from schemas.signal import RAV4_SPEED, SignalDef, check

DEFAULT_FOLLOW = "/etc/libpanda.d/currentCan.csv"
DEFAULT_STALE_SECONDS = 10.0  # the RAV4 sends SPEED ~1.6 times a second, with gaps up to 6 s
DEFAULT_STATIONARY_SECONDS = 60.0
_WINDOW = re.compile(r"^([01]\d|2[0-3]):([0-5]\d)-([01]\d|2[0-4]):([0-5]\d)$")
_MAX_ID = 0x1FFFFFFF  # 29-bit extended identifiers

BUS_INTERFACES: tuple[str, ...] = (
    "canalystii", "cantact", "etas", "gs_usb", "iscan", "ixxat", "kvaser", "neousys", "neovi",
    "nican", "nixnet", "pcan", "robotell", "seeedstudio", "serial", "slcan", "socketcan",
    "socketcand", "systec", "udp_multicast", "usb2can", "vector", "virtual",
)
"""The bus interfaces python-can ships (the same 23 from 4.5 to 4.6.1), sorted: written out
because schemas/ imports nothing that reaches outside the process, and held equal to
python-can's own list by tests/contract/test_can_sources.py. An interface added by a
python-can plugin is not in it."""


def check_path(value: str, what: str) -> str:
    parts = value.split("/")
    if not value or "\x00" in value or ".." in parts or len(value) > 4096:
        raise ValueError(f"{what} {value!r} must be a path without '..'")
    return value


def check_frame_id(value: int, what: str = "id") -> int:
    if not 0 <= value <= _MAX_ID:
        raise ValueError(f"{what} {value} is not a CAN identifier (0 to 0x1FFFFFFF)")
    return value


def parse_window(text: str) -> tuple[int, int]:
    """'22:00-06:00' → (start, end) in minutes after midnight; the end may be the next day."""
    match = _WINDOW.fullmatch(text)
    if match is None:
        raise ValueError(f"window {text!r} is not a time range HH:MM-HH:MM (24-hour, local "
                         "time), e.g. '22:00-06:00'")
    start = int(match[1]) * 60 + int(match[2])
    end = int(match[3]) * 60 + int(match[4])
    if end > 24 * 60:
        raise ValueError(f"window {text!r} ends after 24:00")
    if start == end:
        raise ValueError(f"window {text!r} is empty; to allow any time, give no windows")
    return start, end


class SourceSpec(BaseModel):
    """Where the frames come from: exactly one of `bus`, `follow` or `log`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    bus: dict[StrictStr, StrictStr | StrictInt | float | bool] | None = Field(
        default=None, description="python-can bus settings, passed as can.Bus(**bus); "
        "`interface` is required (socketcan, socketcand, virtual, …)")
    follow: StrictStr | None = Field(
        default=None, description="a libpanda CSV followed as it grows (a symlink is "
        "followed to each new recording)")
    log: StrictStr | None = Field(
        default=None, description="a log python-can reads: candump .log, .asc, .blf")

    @field_validator("follow", "log")
    @classmethod
    def _path(cls, value: str | None) -> str | None:
        return None if value is None else check_path(value, "source path")

    @field_validator("bus")
    @classmethod
    def _bus(cls, value: dict[str, Any] | None) -> dict[str, Any] | None:
        if value is None:
            return None
        interface = value.get("interface")
        if not isinstance(interface, str):
            raise ValueError("bus needs `interface:` (socketcan on a CAN HAT, socketcand, "
                             "virtual, …)")
        if interface not in BUS_INTERFACES:
            raise ValueError(f"bus interface {interface!r} is not one python-can knows: "
                             f"{', '.join(BUS_INTERFACES)}")
        return value

    @model_validator(mode="after")
    def _one(self) -> SourceSpec:
        if sum(x is not None for x in (self.bus, self.follow, self.log)) != 1:
            raise ValueError("give exactly one of `bus:`, `follow:` or `log:`")
        return self


class SignalSpec(BaseModel):
    """One signal: inline as a DBC line writes it, or a signal of a DBC file."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: StrictInt | None = Field(default=None, description="the message's CAN id (0xB4)")
    start_bit: StrictInt | None = Field(default=None, description="as in DBC `47|16@0+`")
    length: StrictInt | None = Field(default=None, description="bits")
    byte_order: Literal["big_endian", "little_endian"] = Field(
        default="big_endian", description="@0 (Motorola) is big_endian, @1 little_endian")
    signed: bool = False
    scale: float = 1.0
    offset: float = 0.0
    dbc: StrictStr | None = Field(default=None, description="a DBC file (relative to "
                                  "the desired state's folder), read with cantools")
    message: StrictStr | StrictInt | None = Field(default=None,
                                                  description="the DBC message, name or id")
    signal: StrictStr | None = Field(default=None, description="the DBC signal's name")

    @field_validator("id")
    @classmethod
    def _id(cls, value: int | None) -> int | None:
        return None if value is None else check_frame_id(value)

    @model_validator(mode="after")
    def _form(self) -> SignalSpec:
        inline = (self.id, self.start_bit, self.length)
        if self.dbc is not None:
            if any(v is not None for v in inline):
                raise ValueError("give either `dbc:` with `signal:`, or `id:`, `start_bit:` "
                                 "and `length:`, not both")
            if self.signal is None:
                raise ValueError("with `dbc:`, name the signal: `signal: SPEED`")
            check_path(self.dbc, "dbc")
            return self
        if any(v is None for v in inline):
            raise ValueError("a signal needs `id:`, `start_bit:` and `length:` (as a DBC "
                             "line writes `47|16@0+`), or `dbc:` and `signal:`")
        why = check(self.inline())
        if why is not None:
            raise ValueError(why)
        return self

    def inline(self) -> SignalDef:
        assert self.id is not None and self.start_bit is not None and self.length is not None
        return SignalDef(frame_id=self.id, start_bit=self.start_bit, length=self.length,
                         byte_order=self.byte_order, signed=self.signed, scale=self.scale,
                         offset=self.offset, name="speed")


def _rav4_speed() -> SignalSpec:
    s = RAV4_SPEED
    return SignalSpec(id=s.frame_id, start_bit=s.start_bit, length=s.length,
                      byte_order=s.byte_order, signed=s.signed, scale=s.scale, offset=s.offset)


class VehicleSpec(BaseModel):
    """How lpam reads the vehicle: the source of frames and the speed signal."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    source: SourceSpec = Field(default_factory=lambda: SourceSpec(follow=DEFAULT_FOLLOW))
    speed: SignalSpec = Field(default_factory=_rav4_speed,
                              description="default: the RAV4's SPEED, 0xB4 47|16@0+ (0.01,0)")
    stale_seconds: float = Field(default=DEFAULT_STALE_SECONDS, gt=0, le=3600,
                                 description="no speed frame for this long: no signal")


class LockSpec(BaseModel):
    """A lock file an app holds around a critical section (balena's update lock)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    path: StrictStr = Field(description="absolute path (under --root)")
    persistent: bool = Field(default=False, description="held while the file exists (it "
                             "survives a reboot); otherwise held while an app has it flock'ed")

    @field_validator("path")
    @classmethod
    def _path(cls, value: str) -> str:
        check_path(value, "lock")
        if not value.startswith("/"):
            raise ValueError(f"lock {value!r} must be an absolute path, e.g. "
                             "/run/lpam/locks/recording.lock")
        return value


class GatesSpec(BaseModel):
    """When a cutover may happen (module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stationary_seconds: float = Field(default=DEFAULT_STATIONARY_SECONDS, ge=0, le=86400)
    stationary_below: float = Field(default=0.5, ge=0, description="a speed at or below "
                                    "this (the signal's unit, km/h by default) is standing")
    on_no_signal: Literal["defer", "allow"] = "defer"
    windows: list[StrictStr] = Field(default_factory=list)
    locks: list[LockSpec] = Field(default_factory=list)
    unclaimed: Literal["gated", "free"] = Field(
        default="gated", description="a cutover that touches only apps claiming no "
        "exclusive resource (a recorder, a tracker: no `owns_panda`, no `resources`): "
        "`gated` waits for the gates like any other; `free` changes them while the car "
        "moves. A cutover touching an app that claims anything always waits.")

    @field_validator("windows")
    @classmethod
    def _windows(cls, value: list[str]) -> list[str]:
        for text in value:
            parse_window(text)
        return value

    @field_validator("locks", mode="before")
    @classmethod
    def _lock_shorthand(cls, value: Any) -> Any:
        if isinstance(value, list):
            return [{"path": v} if isinstance(v, str) else v for v in value]
        return value

    def spans(self) -> list[tuple[int, int]]:
        return [parse_window(w) for w in self.windows]

    @model_serializer(mode="wrap")
    def _default_unwritten(self, handler: SerializerFunctionWrapHandler) -> Any:
        """`unclaimed` is dumped only when it is not the default: a desired state's
        fingerprint (what an operator's stop and a rollback hold against) stays the one
        an lpam before several apps took, so an upgrade ends no hold."""
        data = handler(self)
        if isinstance(data, dict) and data.get("unclaimed") == "gated":
            del data["unclaimed"]
        return data


class CanHealth(BaseModel):
    """Message ids the app must put on the bus after it starts."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    ids: list[StrictInt] = Field(min_length=1, description="CAN ids, e.g. [0x2E4]")
    within_seconds: float = Field(default=10.0, gt=0, le=600)

    @field_validator("ids")
    @classmethod
    def _ids(cls, value: list[int]) -> list[int]:
        for item in value:
            check_frame_id(item, "health.can id")
        return value
