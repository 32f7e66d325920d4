"""Whose turn it is in a rollout, and what a car has proven: the pure rules behind the
agent's waves (workflow/waves.py reads the statuses and calls these; no I/O, no clock of
their own).

A rollout (schemas/rollout.py) lists waves of vehicle ids or globs. For one revision R:

- a car is in the first wave that names it; wave 1's turn is at once;
- wave k's turn comes when every car of each earlier wave has *proven* R — it published
  stage `proven`: it ran R, its apps running after their health checks, `prove_seconds`
  with no rollback — or, when the rollout sets `silent_seconds`, has not reported for that
  long and is skipped; a wave whose every car is skipped proves nothing and holds the
  next (a canary that never answered is no evidence);
- a car of an earlier wave that rolled R back (its health check failed, its apply failed)
  halts every later wave, for R alone: the next revision starts a rollout of its own;
- a car no wave names never takes R: the rollout says so rather than guessing a place.

Why the proof is what the car itself publishes, not something the others compute from its
report's times: a car publishes when its status changes or at its heartbeat (hours), so
the others cannot see how long it has run R; the car can, at each pass, and publishing
`proven` is a change, so it goes out at once. The cars trust each other as they trust
the fleet repository they all write to.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime
from fnmatch import fnmatchcase

from schemas.rollout import RolloutSpec, RolloutStage, RolloutState

FAILED = frozenset({"rolled back", "failed"})
"""A pass result by which a car did not take a revision (health rollback, failed apply)."""


@dataclass(frozen=True)
class Peer:
    """Another car as its last published status shows it."""

    vehicle: str
    reported: datetime | None  # its last report (None: never reported)
    rollout: RolloutState | None = None
    attempt: tuple[str | None, str, str | None] | None = None  # (revision, result, reason)


@dataclass(frozen=True)
class Turn:
    """Whether this car may apply the revision now; if not, the stage and why."""

    go: bool
    wave: int | None
    stage: RolloutStage | None = None  # `waiting` or `halted` when it may not
    reason: str | None = None


def wave_of(spec: RolloutSpec, vehicle: str) -> int | None:
    """The wave (1 first) of the first pattern naming `vehicle`; None when none does."""
    for number, wave in enumerate(spec.waves, 1):
        if any(fnmatchcase(vehicle, pattern) for pattern in wave):
            return number
    return None


def members(spec: RolloutSpec, vehicles: Iterable[str]) -> list[list[str]]:
    """The cars of each wave: the known `vehicles` in the first wave naming them, and every
    id a wave names literally (a car that never reported is still a member)."""
    every = set(vehicles) | {p for wave in spec.waves for p in wave if not _glob(p)}
    found: list[list[str]] = [[] for _ in spec.waves]
    for vehicle in sorted(every):
        number = wave_of(spec, vehicle)
        if number is not None:
            found[number - 1].append(vehicle)
    return found


def watched(spec: RolloutSpec, vehicle: str) -> tuple[str, ...]:
    """The patterns of the waves before this car's: the status branches it must read."""
    number = wave_of(spec, vehicle)
    if number is None:
        return ()
    return tuple(p for wave in spec.waves[: number - 1] for p in wave)


def turn(spec: RolloutSpec, vehicle: str, revision: str, peers: Mapping[str, Peer],
         now: datetime) -> Turn:
    """Whether `vehicle` may apply `revision` now, by the other cars' `peers`."""
    number = wave_of(spec, vehicle)
    if number is None:
        return Turn(False, None, "waiting", f"no wave of the rollout names {vehicle}: add it "
                    "to a wave, or add a wave [\"*\"]")
    waves = members(spec, [*peers, vehicle])
    short = revision[:12]
    for earlier, cars in enumerate(waves[: number - 1], 1):
        for car in cars:
            peer = peers.get(car, Peer(car, None))
            why = _rolled_back(peer, revision)
            if why is not None:
                return Turn(False, number, "halted", f"halted: {car} (wave {earlier}) rolled "
                            f"back {short}: {why}. A new revision, or a revert, resumes")
    for earlier, cars in enumerate(waves[: number - 1], 1):
        proven = 0
        for car in cars:
            peer = peers.get(car, Peer(car, None))
            if _proven(peer, revision):
                proven += 1
            elif not _skipped(spec, peer, now):
                return Turn(False, number, "waiting", f"wave {number} waits for wave "
                            f"{earlier} to prove {short}: {car} {_where(spec, peer, revision)}")
        if proven == 0:
            return Turn(False, number, "waiting", f"wave {number} waits for wave {earlier} "
                        f"to prove {short}: none of its cars ({', '.join(cars) or 'none'}) "
                        "has reported it proven")
    return Turn(True, number)


def stage_of(spec: RolloutSpec, ran: float, *, running: bool) -> \
        tuple[RolloutStage, str | None]:
    """This car's own stage once it has run the revision `ran` seconds: proven after
    `prove_seconds` with its apps running, else proving (and why it is not proven yet).
    `ran` is measured on the boot's monotonic clock (workflow/waves.py): a Pi's wall clock
    jumps hours when GPS or NTP sets it after a boot, which must not prove anything."""
    if not running:
        return "proving", "an app does not run: the proof waits until it runs again"
    if ran >= spec.prove_seconds:
        return "proven", None
    return "proving", f"ran it {int(ran)} s of {spec.prove_seconds:g} s"


def _glob(pattern: str) -> bool:
    return any(c in pattern for c in "*?[")


def _rolled_back(peer: Peer, revision: str) -> str | None:
    state = peer.rollout
    if state is not None and state.revision == revision and state.stage == "rolled back":
        return state.reason or "rolled back"
    if peer.attempt is not None and peer.attempt[0] == revision and peer.attempt[1] in FAILED:
        return peer.attempt[2] or peer.attempt[1]
    return None


def _proven(peer: Peer, revision: str) -> bool:
    state = peer.rollout
    return state is not None and state.revision == revision and state.stage == "proven"


def _skipped(spec: RolloutSpec, peer: Peer, now: datetime) -> bool:
    if spec.silent_seconds is None:
        return False
    return peer.reported is None or \
        (now - peer.reported).total_seconds() >= spec.silent_seconds


def _where(spec: RolloutSpec, peer: Peer, revision: str) -> str:
    """Why a car of an earlier wave holds the next: what its last report says."""
    if peer.reported is None:
        return "has never reported" + _silence(spec)
    seen = peer.reported.isoformat(timespec="seconds")
    state = peer.rollout
    if state is not None and state.revision == revision and state.stage == "proving":
        return f"runs it since {state.applied or state.since}, not proven yet " \
            f"(reported {seen})"
    return f"has not reported it running (last report {seen}){_silence(spec)}"


def _silence(spec: RolloutSpec) -> str:
    if spec.silent_seconds is None:
        return "; the rollout sets no silent_seconds, so it holds the waves after it"
    return ""
