"""The rules of waves (core/rollout.py) and the `rollout:` document's checks."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from pydantic import ValidationError

from reconciler.core.rollout import Peer, members, stage_of, turn, watched, wave_of
from schemas.rollout import RolloutSpec, RolloutStage, RolloutState
from schemas.timeline import Stamp

NOW = datetime(2026, 11, 20, 8, 0, tzinfo=timezone.utc)
R = "a" * 40
SPEC = RolloutSpec(waves=[["car-03"], ["car-01", "car-02"], ["*"]], prove_seconds=600)


def peer(vehicle: str, stage: RolloutStage | None, *, revision: str = R,
         minutes_ago: float = 1, reason: str | None = None) -> Peer:
    state = None if stage is None else RolloutState(
        revision=revision, wave=1, stage=stage, since="2026-11-20T07:00:00+00:00",
        reason=reason)
    return Peer(vehicle, NOW - timedelta(minutes=minutes_ago), state)


def test_a_car_is_in_the_first_wave_that_names_it() -> None:
    assert [wave_of(SPEC, v) for v in ("car-03", "car-02", "car-09")] == [1, 2, 3]
    assert wave_of(RolloutSpec(waves=[["rav4-*"]]), "prius-1") is None
    assert members(SPEC, ["car-09", "car-01"]) == [["car-03"], ["car-01", "car-02"],
                                                   ["car-09"]]
    assert watched(SPEC, "car-09") == ("car-03", "car-01", "car-02")
    assert watched(SPEC, "car-03") == ()


def test_the_canary_goes_at_once_and_the_next_wave_waits_for_its_proof() -> None:
    assert turn(SPEC, "car-03", R, {}, NOW).go
    for stage in (None, "proving", "waiting"):
        waits = turn(SPEC, "car-01", R, {"car-03": peer("car-03", stage)}, NOW)
        assert not waits.go and waits.stage == "waiting" and waits.wave == 2
        assert "car-03" in (waits.reason or "")
    assert turn(SPEC, "car-01", R, {"car-03": peer("car-03", "proven")}, NOW).go


def test_a_proof_of_another_revision_proves_nothing() -> None:
    old = peer("car-03", "proven", revision="b" * 40)
    assert not turn(SPEC, "car-01", R, {"car-03": old}, NOW).go


def test_every_car_of_every_earlier_wave_must_prove_it() -> None:
    peers = {"car-03": peer("car-03", "proven"), "car-01": peer("car-01", "proven"),
             "car-02": peer("car-02", "proving")}
    waits = turn(SPEC, "car-07", R, peers, NOW)
    assert not waits.go and "car-02" in (waits.reason or "") and waits.wave == 3
    peers["car-02"] = peer("car-02", "proven")
    assert turn(SPEC, "car-07", R, peers, NOW).go


def test_a_rollback_in_an_earlier_wave_halts_the_later_ones() -> None:
    peers = {"car-03": peer("car-03", "rolled back", reason="health check failed")}
    for vehicle in ("car-01", "car-07"):
        halted = turn(SPEC, vehicle, R, peers, NOW)
        assert not halted.go and halted.stage == "halted"
        assert "car-03 (wave 1) rolled back" in (halted.reason or "")
        assert "health check failed" in (halted.reason or "")
    assert turn(SPEC, "car-03", R, peers, NOW).go  # its own wave: not halted by itself
    # a failed attempt in its published pass counts the same
    failed = Peer("car-03", NOW, None, (R, "rolled back", "ctl-bad: health"))
    assert turn(SPEC, "car-01", R, {"car-03": failed}, NOW).stage == "halted"
    # a rollback of another revision halts nothing
    other = {"car-03": peer("car-03", "rolled back", revision="b" * 40)}
    assert turn(SPEC, "car-01", R, other, NOW).stage == "waiting"


def test_a_silent_car_blocks_unless_the_rollout_skips_it() -> None:
    peers = {"car-03": peer("car-03", "proven"), "car-01": peer("car-01", "proven"),
             "car-02": peer("car-02", None, minutes_ago=180)}
    waits = turn(SPEC, "car-07", R, peers, NOW)
    assert not waits.go and "car-02" in (waits.reason or "")
    assert "silent_seconds" in (waits.reason or "")  # it says what would skip it
    skipping = SPEC.model_copy(update={"silent_seconds": 7200})
    assert turn(skipping, "car-07", R, peers, NOW).go
    peers["car-02"] = peer("car-02", None, minutes_ago=100)  # silent, but not 2 h
    assert not turn(skipping, "car-07", R, peers, NOW).go
    # a car named in a wave that never reported at all is silent since forever
    del peers["car-02"]
    assert not turn(SPEC, "car-07", R, peers, NOW).go
    assert turn(skipping, "car-07", R, peers, NOW).go


def test_a_wave_whose_every_car_is_skipped_proves_nothing() -> None:
    skipping = SPEC.model_copy(update={"silent_seconds": 60})
    waits = turn(skipping, "car-01", R, {"car-03": peer("car-03", None, minutes_ago=90)},
                 NOW)
    assert not waits.go and "none of its cars" in (waits.reason or "")


def test_a_car_no_wave_names_never_takes_the_revision() -> None:
    spec = RolloutSpec(waves=[["car-03"], ["car-0[12]"]])
    found = turn(spec, "car-09", R, {"car-03": peer("car-03", "proven")}, NOW)
    assert not found.go and found.wave is None and "no wave" in (found.reason or "")


def test_a_car_proves_the_revision_after_prove_seconds_with_its_apps_running() -> None:
    assert stage_of(SPEC, 599, running=True)[0] == "proving"
    assert stage_of(SPEC, 600, running=True) == ("proven", None)
    stage, why = stage_of(SPEC, 3600, running=False)
    assert stage == "proving" and "does not run" in (why or "")


def stamp(boot: str, mono: float, wall: datetime) -> Stamp:
    return Stamp(boot=boot, mono=mono, wall=wall)


def test_the_proof_is_counted_on_the_boot_clock_not_the_wall_clock_a_pi_sets_late() -> None:
    from reconciler.workflow.waves import after

    applied = after(SPEC, "car-03", R, "applied", None, None, running=True,
                    stamp=stamp("b1", 40.0, NOW))
    assert applied is not None and applied.stage == "proving"
    # GPS sets the clock five hours on, one minute later: nothing is proven by that
    jumped = after(SPEC, "car-03", R, "nothing to do", None, applied, running=True,
                   stamp=stamp("b1", 100.0, NOW + timedelta(hours=5)))
    assert jumped is not None and jumped.stage == "proving"
    proven = after(SPEC, "car-03", R, "nothing to do", None, jumped, running=True,
                   stamp=stamp("b1", 640.0, NOW + timedelta(hours=5, minutes=9)))
    assert proven is not None and proven.stage == "proven"
    assert proven.applied == applied.applied  # when it applied, as the wall clock said
    # a reboot starts the apps again, and the proof with them (from the boot's start)
    rebooted = after(SPEC, "car-03", R, "nothing to do", None, proven, running=True,
                     stamp=stamp("b2", 30.0, NOW + timedelta(hours=6)))
    assert rebooted is not None and rebooted.stage == "proving"
    assert (rebooted.boot, rebooted.mono) == ("b2", 0.0)
    again = after(SPEC, "car-03", R, "nothing to do", None, rebooted, running=True,
                  stamp=stamp("b2", 600.0, NOW + timedelta(hours=6, minutes=10)))
    assert again is not None and again.stage == "proven"


@pytest.mark.parametrize(("waves", "said"), [
    ([], "at least 1"),
    ([["car-03"], []], "wave 2 is empty"),
    ([["car-03"], ["car-03"]], "named twice"),
    ([["car 03"]], "a vehicle id or a glob"),
    ([["../x"]], "a vehicle id or a glob"),
])
def test_a_bad_rollout_is_refused_with_what_to_do(waves: list[list[str]], said: str) -> None:
    with pytest.raises(ValidationError) as caught:
        RolloutSpec(waves=waves)
    assert said in str(caught.value)


def test_an_offline_pass_decides_from_the_statuses_it_holds_without_a_second_fetch(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With no network, a waiting car must not try the network again for the statuses
    (a hotspot's timeout per pass): the store's copies decide, and prove nothing new."""
    from reconciler.base.layout import Layout
    from reconciler.workflow import waves
    from reconciler.workflow.machine import Machine
    from schemas.agent import AgentConfig, AgentStatus

    asked: list[tuple[str, ...]] = []
    monkeypatch.setattr(waves, "_fetch_statuses", lambda machine, config, globs:
                        asked.append(globs))
    machine = Machine(Layout(tmp_path))
    config = AgentConfig.model_validate({"version": 1, "source": {
        "url": "git://127.0.0.1:9/fleet.git"}, "vehicle": "car-01"})
    for fetched, expected in ((None, []), ((), [("car-03",)]), (("car-03",), [])):
        asked.clear()
        wait = waves.held(machine, config, SPEC, "car-01", R, AgentStatus(),
                          fetched=fetched, now=NOW)
        assert wait is not None and wait.stage == "waiting" and wait.wave == 2
        assert asked == expected, fetched
