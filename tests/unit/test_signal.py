"""Reading one signal from a CAN frame: the RAV4's speed from the generated drive and, where
`../shared/data` is beside the checkout, from the real one it is shaped after (skipped,
saying why, elsewhere), `decode` against cantools' own decoding for any signal a classic
frame can hold, `check` naming each way a definition cannot fit, and `from_dbc` turning a
DBC file into a definition or a ConfigError that names the file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from cantools.database.can import Message, Signal
from cantools.database.conversion import BaseConversion
from cantools.errors import Error as CantoolsError
from hypothesis import example, given, settings
from hypothesis import strategies as st

from reconciler.adapters.can.dbc import from_dbc
from reconciler.base.errors import ConfigError
from reconciler.core.vehicle.signal import RAV4_SPEED, ByteOrder, SignalDef, check, decode, raw
from tests.canlog import candump_line, drive, recorded_text

FRAME = re.compile(r"^\((?P<ts>[\d.]+)\) \S+ (?P<id>[0-9A-F]+)#(?P<data>[0-9A-F]*)$")

RAV4_DBC = """VERSION ""

BO_ 180 SPEED: 8 XXX
 SG_ ENCODER : 39|8@0+ (1,0) [0|255] "" XXX
 SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h" XXX
 SG_ CHECKSUM : 63|8@0+ (1,0) [0|255] "" XXX
"""


def speed_frames(text: str) -> dict[str, bytes]:
    """Every SPEED (0x0B4) frame of a candump log's text, by its timestamp as written."""
    frames = {}
    for line in text.splitlines():
        match = FRAME.match(line)
        if match and int(match["id"], 16) == RAV4_SPEED.frame_id:
            frames[match["ts"]] = bytes.fromhex(match["data"])
    return frames


@pytest.fixture(scope="module")
def generated() -> dict[str, bytes]:
    """The generated drive's SPEED frames, read back from the log text it is written as."""
    return speed_frames("".join(candump_line(m) for m in drive()))


@pytest.fixture(scope="module")
def recorded() -> dict[str, bytes]:
    """The real drive's SPEED frames (the test is skipped without ../shared/data)."""
    return speed_frames(recorded_text())


# Frames of the generated drive and their speed worked out by hand: bytes 5 and 6,
# big-endian, x 0.01.
@pytest.mark.parametrize(("timestamp", "data", "speed"), [
    ("1717236000.020596", "00000000000000BC", 0.0),    # 00 00: standing at the start
    ("1717236121.521356", "00000000000034F0", 0.52),   # 00 34 = 52: pulling away
    ("1717236163.021374", "00000000DD0F9C44", 39.96),  # 0F 9C = 3996
    ("1717236199.770485", "000000009F168DFE", 57.73),  # 16 8D = 5773: cruising
    ("1717236280.520881", "00000000E50054F5", 0.84),   # 00 54 = 84: braking for the light
    ("1717236480.020234", "00000000D803079E", 7.75),   # 03 07 = 775: slowing for a turn
    ("1717236779.771098", "00000000120000CE", 0.0),    # parked at the end
])
def test_rav4_speed_from_the_generated_drive(
        generated: dict[str, bytes], timestamp: str, data: str, speed: float) -> None:
    frame = generated[timestamp]
    assert frame == bytes.fromhex(data)
    assert decode(RAV4_SPEED, frame) == pytest.approx(speed, abs=1e-9)


def test_the_whole_generated_drive_reads_as_its_profile(generated: dict[str, bytes]) -> None:
    speeds = [decode(RAV4_SPEED, data) for data in generated.values()]
    assert len(speeds) == 3120  # 780 s, four a second
    assert None not in speeds
    assert speeds[0] == speeds[-1] == 0.0  # stands at the start and the end
    assert max(s for s in speeds if s is not None) == pytest.approx(58.15)


# Frames of the real drive and their speed worked out by hand from bytes 5-6, as above (only
# the speed is kept here, not the recording's bytes).
@pytest.mark.parametrize(("timestamp", "speed"), [
    ("1628870267.338682", 0.0),    # 00 00: standing at the start
    ("1628870389.455381", 2.33),   # 00 E9 = 233: moving off
    ("1628870433.974374", 31.09),  # 0C 25 = 3109
    ("1628870493.638699", 57.51),  # 16 77 = 5751: near the top speed
    ("1628870688.664435", 47.73),  # 12 A5 = 4773
    ("1628870997.926276", 0.0),    # parked at the end
])
def test_rav4_speed_from_the_recorded_drive(
        recorded: dict[str, bytes], timestamp: str, speed: float) -> None:
    assert decode(RAV4_SPEED, recorded[timestamp]) == pytest.approx(speed, abs=1e-9)


def test_the_whole_recorded_drive_reads_as_its_readme_describes(
        recorded: dict[str, bytes]) -> None:
    speeds = [decode(RAV4_SPEED, data) for data in recorded.values()]
    assert len(speeds) == 1279
    assert None not in speeds
    assert speeds[0] == speeds[-1] == 0.0  # stands at the start and the end
    assert max(s for s in speeds if s is not None) == pytest.approx(58.49)


def test_a_frame_too_short_for_the_signal_is_no_signal() -> None:
    assert decode(RAV4_SPEED, bytes.fromhex("000000006800E9")) == pytest.approx(2.33)  # 7 bytes
    assert decode(RAV4_SPEED, bytes.fromhex("000000006800")) is None  # ends inside SPEED
    assert decode(RAV4_SPEED, b"") is None
    intel = SignalDef(0x10, 56, 8, "little_endian")
    assert decode(intel, bytes(7)) is None
    assert decode(intel, bytes([0] * 7 + [0x2A])) == 42.0


def test_signed_signals_are_twos_complement() -> None:
    steer = SignalDef(0x25, 3, 12, "big_endian", signed=True, scale=1.5)  # Toyota STEER_ANGLE
    assert raw(steer, bytes.fromhex("0FFF000000000000")) == -1
    assert decode(steer, bytes.fromhex("0800000000000000")) == -2048 * 1.5
    assert decode(steer, bytes.fromhex("07FF000000000000")) == 2047 * 1.5


# --- decode agrees with cantools for every signal that fits a classic frame -------------

@st.composite
def fitting_signals(draw: st.DrawFn) -> SignalDef:
    order: ByteOrder = draw(st.sampled_from(["big_endian", "little_endian"]))
    length = draw(st.integers(1, 64))
    first = draw(st.integers(0, 64 - length))  # the first bit in the frame's own order
    start = first if order == "little_endian" else (first // 8) * 8 + 7 - first % 8
    scale = draw(st.sampled_from([1.0, 0.01, 2.0, -0.5, 3.0]) | st.floats(
        -1e3, 1e3, allow_nan=False, allow_infinity=False).filter(lambda x: x != 0))
    offset = draw(st.sampled_from([0.0, -40.0, 7.0]) | st.floats(
        -1e6, 1e6, allow_nan=False, allow_infinity=False))
    return SignalDef(draw(st.integers(0, 0x7FF)), start, length, order,
                     signed=draw(st.booleans()), scale=scale, offset=offset, name="S")


def cantools_message(sig: SignalDef) -> Message:
    """The same signal as cantools builds it from a DBC line (start bit kept as written)."""
    signal = Signal(name=sig.name, start=sig.start_bit, length=sig.length,
                    byte_order=sig.byte_order, is_signed=sig.signed,
                    conversion=BaseConversion.factory(scale=sig.scale, offset=sig.offset))
    return Message(frame_id=sig.frame_id, name="M", length=8, signals=[signal], strict=True)


def cantools_decodes(message: Message, data: bytes, *, scaling: bool) -> int | float:
    decoded = message.decode(data, decode_choices=False, scaling=scaling)
    assert isinstance(decoded, dict)
    value = decoded["S"]
    assert isinstance(value, (int, float))
    return value


@settings(max_examples=400, deadline=None)
@given(fitting_signals(), st.binary(min_size=8, max_size=8))
# A 64-bit raw value times a whole scale: cantools computes it exactly in integers, while
# float(raw) * 3.0 would round twice and differ in the last bit.
@example(SignalDef(0x10, 0, 64, "little_endian", scale=3.0, name="S"),
         bytes.fromhex("c4bb86c3d1c42790"))
def test_decode_agrees_with_cantools(sig: SignalDef, data: bytes) -> None:
    message = cantools_message(sig)
    assert check(sig) is None
    assert raw(sig, data) == cantools_decodes(message, data, scaling=False)
    assert decode(sig, data) == float(cantools_decodes(message, data, scaling=True))


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(["big_endian", "little_endian"]), st.integers(0, 63),
       st.integers(1, 64))
def test_check_fits_exactly_what_cantools_fits(order: ByteOrder, start: int,
                                               length: int) -> None:
    sig = SignalDef(0x10, start, length, order, name="S")
    try:
        cantools_message(sig)
        cantools_fits = True
    except CantoolsError:
        cantools_fits = False
    assert (check(sig) is None) == cantools_fits


# --- check: each kind of misfit, as a sentence ------------------------------------------

def test_the_rav4_speed_fits() -> None:
    assert check(RAV4_SPEED) is None


@pytest.mark.parametrize(("sig", "words"), [
    (SignalDef(1 << 29, 0, 8, "little_endian"), "29 bits"),
    (SignalDef(-1, 0, 8, "little_endian"), "29 bits"),
    (SignalDef(0xB4, 64, 8, "little_endian"), "start bit 64"),
    (SignalDef(0xB4, -1, 8, "big_endian"), "start bit -1"),
    (SignalDef(0xB4, 0, 0, "little_endian"), "length 0"),
    (SignalDef(0xB4, 0, 65, "little_endian"), "length 65"),
    (SignalDef(0xB4, 60, 8, "little_endian"), "runs past the end"),
    (SignalDef(0xB4, 0, 58, "big_endian"), "runs past the end"),  # bit 0 is the 8th bit
    (SignalDef(0xB4, 63, 16, "big_endian"), "runs past the end"),  # 63 is the last byte's MSB
    (SignalDef(0xB4, 47, 16, "big_endian", scale=float("nan")), "finite"),
    (SignalDef(0xB4, 47, 16, "big_endian", offset=float("inf")), "finite"),
    (SignalDef(0xB4, 47, 16, "big_endian", scale=0.0), "scale 0"),
    (SignalDef(0xB4, 47, 16, "middle_endian"), "byte order"),  # type: ignore[arg-type]
])
def test_check_names_each_misfit(sig: SignalDef, words: str) -> None:
    problem = check(sig)
    assert problem is not None
    assert words in problem
    assert "\n" not in problem


def test_check_knows_the_frame_size() -> None:
    problem = check(RAV4_SPEED, frame_bytes=6)
    assert problem is not None and "6-byte frame" in problem
    assert check(SignalDef(0xB4, 7, 64, "big_endian")) is None  # all 64 bits, MSB first


# --- from_dbc ----------------------------------------------------------------------------

def write(tmp_path: Path, text: str, name: str = "car.dbc") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("message", [None, "SPEED", 180])
def test_from_dbc_reads_the_rav4_speed(tmp_path: Path, message: str | int | None) -> None:
    dbc = write(tmp_path, RAV4_DBC)
    assert from_dbc(dbc, message=message, signal="SPEED") == RAV4_SPEED


def dbc_error(path: Path, *, message: str | int | None = None,
              signal: str = "SPEED") -> ConfigError:
    with pytest.raises(ConfigError) as caught:
        from_dbc(path, message=message, signal=signal)
    assert caught.value.path == path
    assert caught.value.hint
    return caught.value


def test_from_dbc_missing_file(tmp_path: Path) -> None:
    error = dbc_error(tmp_path / "nowhere.dbc")
    assert "No such file" in error.message


def test_from_dbc_unparsable_file_points_at_the_line(tmp_path: Path) -> None:
    dbc = write(tmp_path, RAV4_DBC.replace("(0.01,0)", "(0.01,0"))
    error = dbc_error(dbc)
    assert (error.line, error.column) == (5, 31)  # the "[" where ")" belongs
    assert error.render().startswith(f"error: {dbc}:5:31: not a DBC file")


@pytest.mark.parametrize(("message", "signal", "words"), [
    ("BRAKE", "SPEED", "no message BRAKE"),
    (0x1B4, "SPEED", "no message 0x1b4"),
    ("SPEED", "SPEEED", "no signal SPEEED"),
    (None, "SPEEED", "no message has a signal SPEEED"),
])
def test_from_dbc_unknown_names_list_the_known_ones(
        tmp_path: Path, message: str | int | None, signal: str, words: str) -> None:
    error = dbc_error(write(tmp_path, RAV4_DBC), message=message, signal=signal)
    assert words in error.message
    assert "SPEED" in (error.hint or "")


def test_from_dbc_refuses_what_it_cannot_represent(tmp_path: Path) -> None:
    dbc = write(tmp_path, RAV4_DBC + """
BO_ 800 MUXED: 8 XXX
 SG_ PAGE M : 0|8@1+ (1,0) [0|255] "" XXX
 SG_ ODOMETER m1 : 8|32@1+ (1,0) [0|0] "km" XXX
 SG_ YAW : 40|16@1- (1,0) [0|0] "" XXX

BO_ 801 FLOATS: 8 XXX
 SG_ ACCEL : 0|32@1- (1,0) [0|0] "m/s2" XXX
 SG_ SPEED : 32|8@1+ (1,0) [0|0] "" XXX

BO_ 802 ODD: 8 XXX
 SG_ BEYOND : 60|16@1+ (1,0) [0|0] "" XXX

SIG_VALTYPE_ 801 ACCEL : 1;
""")
    assert "multiplexed" in dbc_error(dbc, message="MUXED", signal="ODOMETER").message
    assert from_dbc(dbc, message="MUXED", signal="PAGE").start_bit == 0  # the selector is plain
    assert "float" in dbc_error(dbc, message="FLOATS", signal="ACCEL").message
    assert "runs past the end" in dbc_error(dbc, message="ODD", signal="BEYOND").message
    ambiguous = dbc_error(dbc, signal="SPEED")
    assert "2 messages" in ambiguous.message and "0xb4" in ambiguous.message
    assert from_dbc(dbc, message="SPEED", signal="SPEED") == RAV4_SPEED
