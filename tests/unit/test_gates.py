"""Update gates, the pure parts: the stationary run of speed samples, each gate's decision,
and the `vehicle:` / `gates:` documents' faults named at file:line:column."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError
from reconciler.core.documents import load_desired
from reconciler.core.vehicle.motion import Motion, Tracker
from reconciler.core.vehicle.policy import all_open, decide, within
from schemas.vehicle import GatesSpec, parse_window

NOW = 1_700_000_000.0


def fold(samples: list[tuple[float, float]], *, stale: float = 10.0) -> Tracker:
    tracker = Tracker(below=0.5, stale=stale)
    for t, v in samples:
        tracker.add(NOW + t, v)
    return tracker


def test_standing_counts_from_the_first_standing_sample() -> None:
    tracker = fold([(-40, 30.0), (-30, 0.0), (-20, 0.0), (-10, 0.0), (-1, 0.0)])
    motion = tracker.motion(NOW)
    assert motion.speed == 0.0 and motion.stationary_for == pytest.approx(29.0)


def test_moving_again_resets_the_run() -> None:
    motion = fold([(-30, 0.0), (-20, 0.0), (-5, 12.0), (-1, 0.0)]).motion(NOW)
    assert motion.speed == 0.0
    assert motion.stationary_for == pytest.approx(0.0)


def test_a_gap_longer_than_stale_breaks_the_run_nothing_is_known_during_it() -> None:
    motion = fold([(-100, 0.0), (-80, 0.0), (-9, 0.0), (-1, 0.0)]).motion(NOW)
    assert motion.stationary_for == pytest.approx(8.0)


def test_no_sample_and_a_silent_source_are_no_signal() -> None:
    assert fold([]).motion(NOW).speed is None
    silent = fold([(-60, 0.0), (-30, 0.0)]).motion(NOW)
    assert silent.speed is None and silent.reason is not None and "30 s" in silent.reason


def test_out_of_order_samples_are_ignored() -> None:
    motion = fold([(-20, 0.0), (-12, 0.0), (-5, 0.0), (-10, 40.0)]).motion(NOW)
    assert motion.speed == 0.0 and motion.stationary_for == pytest.approx(15.0)


GATES = GatesSpec(stationary_seconds=60)


def states(motion: Motion, *, gates: GatesSpec = GATES, busy: tuple[str, ...] = (),
           minute: int = 12 * 60) -> dict[str, tuple[bool, str]]:
    found = decide(gates, motion=motion, source="follow x.csv", busy=busy, minute=minute)
    return {s.name: (s.open, s.detail) for s in found}


def test_vehicle_gate_moving_short_stop_and_parked() -> None:
    assert states(Motion(23.4))["vehicle"] == (False, "moving: 23.4 km/h from follow x.csv")
    stop = states(Motion(0.0, stationary_for=18))["vehicle"]
    assert not stop[0] and "18 s of the 60 s" in stop[1]
    parked = states(Motion(0.0, stationary_for=75))["vehicle"]
    assert parked[0] and "75 s" in parked[1]


def test_no_signal_defers_unless_allowed() -> None:
    silent = Motion(None, reason="no speed frame seen")
    assert states(silent)["vehicle"][0] is False
    allow = GatesSpec(on_no_signal="allow")
    assert states(silent, gates=allow)["vehicle"][0] is True


@pytest.mark.parametrize(("window", "minute", "inside"), [
    ("22:00-06:00", 23 * 60, True), ("22:00-06:00", 5 * 60 + 59, True),
    ("22:00-06:00", 6 * 60, False), ("22:00-06:00", 12 * 60, False),
    ("09:30-17:00", 9 * 60 + 30, True), ("09:30-17:00", 17 * 60, False),
    ("00:00-24:00", 0, True), ("00:00-24:00", 24 * 60 - 1, True),
])
def test_windows_wrap_past_midnight(window: str, minute: int, inside: bool) -> None:
    assert within(parse_window(window), minute) is inside
    gate = states(Motion(0.0, stationary_for=99), gates=GatesSpec(windows=[window]),
                  minute=minute)["window"]
    assert gate[0] is inside


def test_each_held_lock_is_a_closed_gate_and_all_must_be_open() -> None:
    gates = GatesSpec(locks=["/run/lpam/locks/a.lock", "/run/lpam/locks/b.lock"])
    parked = Motion(0.0, stationary_for=99)
    found = decide(gates, motion=parked, source="s", busy=["a is held by pid 7"], minute=0)
    assert [(s.name, s.open) for s in found] == [
        ("vehicle", True), ("window", True), ("lock", False)]
    assert not all_open(found)
    free = decide(gates, motion=parked, source="s", busy=[], minute=0)
    assert all_open(free)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "desired.yaml"
    path.write_text("version: 1\n" + text)
    return path


def test_defaults_are_the_rav4_speed_from_the_recording_and_no_gates(tmp_path: Path) -> None:
    desired = load_desired(write(tmp_path, "app: null\n"))
    assert desired.gates is None
    speed = desired.vehicle.speed.inline()
    assert (speed.frame_id, speed.start_bit, speed.length, speed.byte_order, speed.scale) == (
        0xB4, 47, 16, "big_endian", 0.01)
    assert desired.vehicle.source.follow == "/etc/libpanda.d/currentCan.csv"
    assert desired.vehicle.stale_seconds == 10


def test_the_issue_example_is_valid(tmp_path: Path) -> None:
    desired = load_desired(write(tmp_path, """\
vehicle:
  source: {bus: {interface: socketcand, host: 127.0.0.1, port: 29536, channel: can0}}
  speed: {id: 0xB4, start_bit: 47, length: 16, byte_order: big_endian, scale: 0.01}
gates:
  stationary_seconds: 60
  on_no_signal: defer
  windows: ["22:00-06:00"]
  locks: [/run/lpam/locks/recording.lock, {path: /var/lib/lpam/exp.lock, persistent: true}]
"""))
    assert desired.gates is not None and desired.gates.spans() == [(22 * 60, 6 * 60)]
    assert [(lk.path, lk.persistent) for lk in desired.gates.locks] == [
        ("/run/lpam/locks/recording.lock", False), ("/var/lib/lpam/exp.lock", True)]
    assert desired.vehicle.source.bus == {"interface": "socketcand", "host": "127.0.0.1",
                                          "port": 29536, "channel": "can0"}


@pytest.mark.parametrize(("text", "line", "words"), [
    ("gates:\n  windows: ['25:00-06:00']\n", 3, "not a time range"),
    ("gates:\n  windows: ['06:00-06:00']\n", 3, "empty"),
    ("gates:\n  on_no_signal: maybe\n", 3, "defer"),
    ("gates:\n  locks: [relative.lock]\n", 3, "absolute"),
    ("vehicle:\n  speed: {id: 0xB4, start_bit: 70, length: 16}\n", 3, "start bit"),
    ("vehicle:\n  speed: {id: 0xB4, start_bit: 7, length: 80}\n", 3, "length"),
    ("vehicle:\n  speed: {id: 0xB4, start_bit: 47}\n", 3, "length"),
    ("vehicle:\n  source: {bus: {interface: warp, channel: can0}}\n", 3, "warp"),
    ("vehicle:\n  source: {follow: a.csv, log: b.log}\n", 3, "exactly one"),
    ("vehicle:\n  stale_seconds: -1\n", 3, "greater than 0"),
])
def test_bad_vehicle_and_gates_name_line_and_column(
    tmp_path: Path, text: str, line: int, words: str,
) -> None:
    with pytest.raises(ConfigError) as info:
        load_desired(write(tmp_path, text))
    error = info.value
    assert error.line == line and error.column is not None, error.render()
    assert words in error.render(), error.render()
    assert error.render().startswith(f"error: {tmp_path / 'desired.yaml'}:{line}:")


def test_the_readmes_gate_examples_are_valid(tmp_path: Path) -> None:
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    blocks = [b.split("```", 1)[0] for b in readme.split("```yaml\n")[1:]]
    gated = [b for b in blocks if "\ngates:" in "\n" + b]
    assert len(gated) >= 2
    for block in gated:
        path = tmp_path / "readme.yaml"
        path.write_text(block if "\nversion: 1" in "\n" + block else "version: 1\n" + block)
        assert load_desired(path).gates is not None
