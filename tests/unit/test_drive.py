"""The generated drive (tests/drive.py) is what the gate tests take it for: the profile's
stops where its docstring says, the RAV4's SPEED layout as cantools reads it from opendbc's
definition (not as lpam's own decoder does, which it tests), every id at its period, ids
besides SPEED that a reader which forgot to filter would misread, the same bytes on every
run and every machine — and, where `../shared/data` lies beside the checkout, the shape of
the real drive it stands in for (skipped, saying why, elsewhere)."""

from __future__ import annotations

import gzip
import hashlib
import itertools
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import can
import pytest
from cantools.database.can import Database

from tests import drive
from tests.canlog import recorded_drive

REPO = Path(__file__).resolve().parents[2]

RAV4_DBC = """VERSION ""

BO_ 180 SPEED: 8 XXX
 SG_ ENCODER : 39|8@0+ (1,0) [0|255] "" XXX
 SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h" XXX
 SG_ CHECKSUM : 63|8@0+ (1,0) [0|255] "" XXX
"""


def since_start(stamp: float) -> float:
    return stamp - drive.START


def test_speed_frames_read_with_cantools_are_the_profiles_samples() -> None:
    database = Database()
    database.add_dbc_string(RAV4_DBC)
    message = database.get_message_by_name("SPEED")
    frames = [m for m in drive.frames() if m.arbitration_id == drive.SPEED_ID]
    samples = drive.speeds()
    assert len(frames) == len(samples) == 3120  # 780 s, four a second
    for msg, (t, kmh) in zip(frames, samples):
        assert -1e-6 <= since_start(msg.timestamp) - t <= drive.JITTER + 1e-6
        decoded = message.decode(bytes(msg.data), decode_choices=False)
        assert isinstance(decoded, dict)
        assert decoded["SPEED"] == pytest.approx(kmh, abs=1e-9)
        assert decoded["CHECKSUM"] == drive.checksum(drive.SPEED_ID, bytes(msg.data))


def test_the_toyota_checksum_worked_by_hand() -> None:
    # 0xB4 + 0x00 (the id's bytes) + 8 (the length) + 0x60 = 0x11C: 0x1C
    assert drive.checksum(0xB4, bytes.fromhex("000000006000001C")) == 0x1C
    # 0xB4 + 8 + 0x9F + 0x16 + 0x8D = 0x1FE: 0xFE; bytes 5-6 0x168D = 5773: 57.73 km/h
    assert drive.speed_data(57.73, 0x9F) == bytes.fromhex("000000009F168DFE")


def standing_runs(samples: Sequence[tuple[float, float]] | None = None,
                  threshold: float = 0.5) -> list[tuple[float, float]]:
    """(first, last) time of each run of speed samples (time, km/h; the generated drive's
    unless given) at or below `threshold` km/h, as the gate's tracker counts a standstill."""
    runs = []
    for low, group in itertools.groupby(drive.speeds() if samples is None else samples,
                                        key=lambda s: s[1] <= threshold):
        if low:
            times = [t for t, _ in group]
            runs.append((round(times[0], 2), round(times[-1], 2)))
    return runs


def test_the_car_stands_parks_and_stops_where_the_profile_says() -> None:
    assert standing_runs() == [
        (0.02, 121.27),     # standing before it leaves (pulling away at 0.27 km/h)
        (143.27, 147.27),   # a short stop on the way out
        (280.77, 299.02),   # the light: 18 s
        (651.27, 654.02),   # in the car park, before reversing
        (668.77, 779.77),   # parked to the end
    ]
    moving = [kmh for t, kmh in drive.speeds() if 312 <= t < 346 or 175 <= t < 265]
    assert all(57.4 < kmh < 58.0 for kmh in moving)  # cruising at about 57.7 km/h
    assert max(kmh for _, kmh in drive.speeds()) == pytest.approx(58.15)


def test_every_id_repeats_at_its_period_in_time_order() -> None:
    frames = drive.frames()
    stamps = [m.timestamp for m in frames]
    assert stamps == sorted(stamps)
    assert len(frames) / drive.DURATION == pytest.approx(80.0)
    for spec in drive.FRAMES:
        own = [since_start(m.timestamp) for m in frames if m.arbitration_id == spec.ident]
        assert len(own) == round(drive.DURATION / spec.period)
        assert all(len(m.data) == spec.length for m in frames
                   if m.arbitration_id == spec.ident)
        gaps = [b - a for a, b in zip(own, own[1:])]
        assert all(abs(gap - spec.period) <= drive.JITTER + 1e-6 for gap in gaps), spec
    assert all(m.channel == "can0" and not m.is_extended_id for m in frames)


def test_a_reader_that_ignores_the_id_would_see_a_parked_car_move() -> None:
    """Bytes 5-6 of the other long frames are never zero: read as SPEED they would say the
    car moves, so the gate tests fail unless lpam filters by id."""
    parked = [m for m in drive.frames() if since_start(m.timestamp) > 700]
    others = [m for m in parked if m.arbitration_id != drive.SPEED_ID and len(m.data) >= 7]
    assert others and all(int.from_bytes(m.data[5:7], "big") > 50 for m in others
                          if m.arbitration_id == drive.WHEEL_SPEEDS_ID)
    assert {m.arbitration_id for m in others} == {0x025, 0x0AA, 0x1D2, 0x224}
    assert sum(int.from_bytes(m.data[5:7], "big") == 0 for m in others) < len(others) / 100


def test_the_log_round_trips_through_python_can_gzip_or_not(tmp_path: Path) -> None:
    for name in ("drive.log", "drive.log.gz"):
        path = drive.write_log(tmp_path / name)
        with gzip.open(path, "rt") if name.endswith(".gz") else path.open() as text:
            back = list(can.CanutilsLogReader(text))
        assert [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in back] == [
            (m.timestamp, m.arbitration_id, bytes(m.data)) for m in drive.frames()]
    first = (tmp_path / "drive.log").read_text().splitlines()[0]
    assert first == "(1717236000.000762) can0 025#000000000000002D"


def test_the_same_bytes_in_another_process_with_another_hash_seed(tmp_path: Path) -> None:
    """No randomness but seeded `random.Random`, no set or dict order, no time in the gzip
    header: `python -m tests.drive` writes what this process writes."""
    here = drive.write_log(tmp_path / "here.log.gz")
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    done = subprocess.run([sys.executable, "-m", "tests.drive", str(tmp_path / "there.log.gz")],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=60,
                          check=False)
    assert done.returncode == 0, done.stderr
    assert "62400 frames in 780 s" in done.stdout

    def digest(path: Path) -> str:
        return hashlib.sha256(path.read_bytes()).hexdigest()

    assert digest(tmp_path / "there.log.gz") == digest(here)


def test_it_is_shaped_like_the_recorded_drive() -> None:
    """The real drive's standstills of 10 s or more — before it leaves, at the light,
    parked — begin and end within 3 s of the generated one's; both have a short stop on the
    way out and one in the car park; their top speeds are within 0.5 km/h; both carry 70-90
    frames a second."""
    real = recorded_drive()
    start = real[0].timestamp
    samples = [(m.timestamp - start, int.from_bytes(m.data[5:7], "big") * 0.01)
               for m in real if m.arbitration_id == drive.SPEED_ID]
    theirs, ours = standing_runs(samples), standing_runs()

    def long(runs: list[tuple[float, float]]) -> list[tuple[float, float]]:
        return [(a, b) for a, b in runs if b - a >= 10]

    assert len(long(theirs)) == len(long(ours)) == 3
    for (a, b), (c, d) in zip(long(theirs), long(ours)):
        assert abs(a - c) <= 3 and abs(b - d) <= 3, ((a, b), (c, d))
    for runs in (theirs, ours):
        assert any(a > 121 and b < 160 for a, b in runs if b - a < 10)  # on the way out
        assert any(a > 640 and b < 668 for a, b in runs if b - a < 10)  # in the car park
    assert max(s for _, s in samples) == pytest.approx(max(s for _, s in drive.speeds()),
                                                       abs=0.5)
    assert 70 < len(real) / (real[-1].timestamp - start) < 90
