"""reconciler/core/privzone/framing.py: what lpam notifies reaches the phone whole, and what a
phone writes reaches lpam whole, whatever the characters and wherever the cuts fall.

The phone is played by tests/unit/privzone_phone.js under node, which decodes and cuts as
Privzone's MapPage.js does (a fresh TextDecoder per notification, 500-character slices).
"""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reconciler.core.privzone.framing import (
    NOTIFICATION_LIMIT,
    STATUS_LIMIT,
    Delivery,
    Inbox,
    Refusal,
    encode_message,
    encode_status,
    split_utf8,
    too_long_text,
    utf16_length,
)
from reconciler.core.privzone.messages import (
    AddRepository,
    AppEnable,
    AppParams,
    RemoveRepository,
    app_info_message,
    parse_input,
)
from tests.records import lpam_row

PHONE = Path(__file__).with_name("privzone_phone.js")
NODE = shutil.which("node")
needs_node = pytest.mark.skipif(NODE is None, reason="node is not installed: the phone's "
                                "decoding is checked by a node script")
EMOJI = "\U0001f697"  # 🚗: four bytes of UTF-8, two UTF-16 units
CJK = "車両"  # three bytes each
DEVICE = "/org/bluez/hci0/dev_AA_BB_CC_DD_EE_01"


def run_phone(mode: str, lines: Sequence[str]) -> list[str]:
    assert NODE is not None
    done = subprocess.run([NODE, str(PHONE), mode], input="\n".join(lines) + "\n",
                          capture_output=True, text=True, timeout=60, check=True)
    return [line for line in done.stdout.splitlines() if line]


def phone_receives(notifications: Sequence[bytes]) -> list[dict[str, Any]]:
    """What the phone makes of these notifications, one dict a message."""
    return [json.loads(line) for line in run_phone("receive", [n.hex() for n in notifications])]


def phone_writes(requests: Sequence[dict[str, Any]]) -> list[bytes]:
    """The writes the phone makes to send these requests, in order."""
    return [bytes.fromhex(line) for line in run_phone("send", [json.dumps(r) for r in requests])]


def body_of(notifications: Sequence[bytes]) -> bytes:
    joined = b"".join(notifications)
    assert joined.endswith(b"\x00")
    return joined[:-1]


# --- lengths and cuts -------------------------------------------------------------------

def test_utf16_length_is_what_javascript_counts() -> None:
    assert utf16_length("") == 0
    assert utf16_length("abc") == 3
    assert utf16_length(CJK) == 2
    assert utf16_length(EMOJI) == 2
    assert utf16_length(f"a{EMOJI}é") == 4


def test_a_cut_never_falls_inside_a_character() -> None:
    data = ("a" * 498 + EMOJI + CJK).encode()
    pieces = split_utf8(data, 500)
    assert pieces[0] == b"a" * 498  # the emoji's four bytes do not fit in the last two
    assert b"".join(pieces) == data
    assert all(piece.decode("utf-8") for piece in pieces)


@pytest.mark.parametrize("body_length, sizes", [
    (499, [500]), (500, [501]), (501, [500, 2]), (1000, [500, 501]), (1001, [500, 500, 2]),
])
def test_bodies_at_the_500_byte_boundaries(body_length: int, sizes: list[int]) -> None:
    notifications = encode_message("app_info", contents_for_body(body_length))
    assert len(body_of(notifications)) == body_length
    assert [len(n) for n in notifications] == sizes
    assert [n.endswith(b"\x00") for n in notifications] == [False] * (len(sizes) - 1) + [True]


def contents_for_body(length: int) -> str:
    """A contents string whose message body is exactly `length` bytes."""
    for padding in range(length):
        body = body_of(encode_message("app_info", "x" * padding))
        if len(body) == length:
            return "x" * padding
    raise AssertionError(f"no body of {length} bytes")


def test_the_body_is_bluezones_ascii_json_in_its_key_order() -> None:
    (only,) = encode_message("app_info", [{"app": f"pandarecord{EMOJI}"}])
    body = json.loads(only[:-1])
    assert list(body) == ["type", "contents", "length"]
    assert body["contents"] == '[{"app": "pandarecord\\ud83d\\ude97"}]'
    assert body["length"] == len(body["contents"])
    assert only.isascii()


def test_nan_is_refused_because_the_phone_could_not_parse_it() -> None:
    with pytest.raises(ValueError):
        encode_message("app_info", {"value": float("nan")})


# --- properties of the sending side -----------------------------------------------------

contents_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.text(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(), inner, max_size=4),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(value=contents_values, padding=st.integers(min_value=0, max_value=1100),
       ascii_only=st.booleans(), limit=st.sampled_from([NOTIFICATION_LIMIT, 4, 5, 6, 7, 20]))
def test_every_notification_decodes_alone_and_the_message_round_trips(
        value: object, padding: int, ascii_only: bool, limit: int) -> None:
    """The padding moves the generated text across the notification edges."""
    value = ["p" * padding, value]
    notifications = encode_message("app_info", value, ascii_only=ascii_only, limit=limit)
    text = ""
    for index, notification in enumerate(notifications):
        last = index == len(notifications) - 1
        assert notification.endswith(b"\x00") == last
        payload = notification[:-1] if last else notification
        assert b"\x00" not in payload
        assert len(payload) <= limit
        piece = payload.decode("utf-8")  # strict: a split character would raise here
        assert utf16_length(piece) <= limit
        text += piece
    message = json.loads(text)
    assert message["length"] == utf16_length(message["contents"])
    assert json.loads(message["contents"]) == value


# --- the phone, in node -----------------------------------------------------------------

def edge_cases() -> Iterator[object]:
    """Contents whose multi-byte characters fall on and around every notification edge."""
    for padding in range(440, 520):
        yield "p" * padding + (EMOJI + CJK + "é") * 3
        yield {"description": "d" * padding + EMOJI * 4, "app": CJK}
    yield ""
    yield []
    yield {}
    yield [{"repository": "jmscslgroup/apps", "description": EMOJI * 700 + CJK * 300}]


@needs_node
@pytest.mark.parametrize("limit", [NOTIFICATION_LIMIT, 23])
@pytest.mark.parametrize("ascii_only", [True, False], ids=["ascii", "utf-8"])
def test_the_phone_reads_exactly_the_contents_lpam_sends(ascii_only: bool, limit: int) -> None:
    values = list(edge_cases())
    messages = [encode_message("app_info", value, ascii_only=ascii_only, limit=limit)
                for value in values]
    if not ascii_only and limit == NOTIFICATION_LIMIT:  # a character across the 500th byte
        assert any(body_of(m)[NOTIFICATION_LIMIT] & 0xC0 == 0x80 for m in messages
                   if len(body_of(m)) > NOTIFICATION_LIMIT)
    received = phone_receives([n for message in messages for n in message])
    assert len(received) == len(values)
    for value, got in zip(values, received):
        assert "error" not in got, got
        assert got["type"] == "app_info"
        assert got["contents"] == json.dumps(value, ensure_ascii=ascii_only)
        assert got["parsed"] == value


@needs_node
def test_the_phone_shows_the_app_list_lpam_sends() -> None:
    rows = [lpam_row(f"o/r{i}", "main", f"app{i}", "can", i == 0, i == 1, f"{CJK} {EMOJI} " * i)
            for i in range(12)]
    (got,) = phone_receives(app_info_message(rows))
    assert got["type"] == "app_info"
    assert got["parsed"][0] == {"repository": "o/r0", "branch": "main", "app": "app0",
                                "service": "can", "enabled": "yes", "running": "no",
                                "description": ""}
    assert [row["description"] for row in got["parsed"]] == [f"{CJK} {EMOJI} " * i
                                                             for i in range(12)]
    assert [row["running"] for row in got["parsed"]] == ["no", "yes"] + ["no"] * 10


@needs_node
def test_the_phone_drops_a_message_cut_inside_a_character() -> None:
    """Why the cut backs off: the phone's per-notification decoding turns a split
    character into U+FFFD and its length check drops the message."""
    def message(padding: int) -> bytes:
        contents = json.dumps("x" * padding + EMOJI * 10, ensure_ascii=False)
        return json.dumps({"type": "app_info", "contents": contents,
                           "length": utf16_length(contents)}, ensure_ascii=False).encode()

    padding = next(p for p in range(500) if message(p).index(EMOJI.encode()) == 498)
    body = message(padding)
    naive = [body[:NOTIFICATION_LIMIT], body[NOTIFICATION_LIMIT:] + b"\x00"]
    (got,) = phone_receives(naive)
    assert got["error"] == "Json length mismatch"


# --- phone -> Pi ------------------------------------------------------------------------

@needs_node
def test_lpam_reads_what_the_phone_writes_in_500_character_slices() -> None:
    long_value = "v" * 495 + CJK * 200 + "é" * 300  # multi-byte characters on slice edges
    requests = [
        {"type": "app_enable", "contents": {"app": "pandarecord"}},
        {"type": "app_enable", "contents": {"app": "None"}},
        {"type": "app_add_repository",
         "contents": {"repository": "jmscslgroup/libpanda-default-apps", "branch": "main"}},
        {"type": "app_remove_repository", "contents": {"repository": "jmscslgroup/x"}},
        {"type": "app_params", "contents": {"app": "gps2vsl", "params": {"NOTE": long_value}}},
    ]
    writes = phone_writes(requests)
    assert writes.count(b"\x00") == len(requests)  # the phone's separate NUL writes
    assert max(len(w) for w in writes) > NOTIFICATION_LIMIT  # 500 characters, more bytes
    inbox = Inbox()
    got = [parse_input(d.body) for d in deliveries(inbox, DEVICE, writes)]
    assert got == [
        AppEnable("pandarecord"), AppEnable(None),
        AddRepository("jmscslgroup/libpanda-default-apps", "main"),
        RemoveRepository("jmscslgroup/x"),
        AppParams("gps2vsl", {"NOTE": long_value}),
    ]
    assert inbox.under_way() == []


def deliveries(inbox: Inbox, device: str | None, writes: Sequence[bytes]) -> list[Delivery]:
    out = []
    for write in writes:
        outcome = inbox.feed(device, write)
        assert not isinstance(outcome, Refusal)
        if outcome is not None:
            out.append(outcome)
    return out


@needs_node
def test_the_phone_cuts_an_emoji_in_two_and_lpam_cannot_tell() -> None:
    """The phone's own limitation, kept in view: its 500-character slice can fall between
    the halves of a surrogate pair, TextEncoder writes each half as U+FFFD, and the length
    (in UTF-16 units) still matches. Values lpam checks are ASCII names, so only a
    parameter value can arrive changed."""
    def phone_json(app: str) -> str:  # JSON.stringify: no spaces, non-ASCII as it is
        inner = json.dumps({"app": app, "params": {"NOTE": EMOJI * 300}},
                           separators=(",", ":"), ensure_ascii=False)
        return json.dumps({"type": "app_params", "contents": inner}, separators=(",", ":"),
                          ensure_ascii=False)

    # the first slice ends between two halves when an odd number of units precede the emoji
    app = next(a for a in ("a", "ab") if (500 - phone_json(a).index(EMOJI)) % 2 == 1)
    writes = phone_writes([{"type": "app_params",
                            "contents": {"app": app, "params": {"NOTE": EMOJI * 300}}}])
    (delivery,) = deliveries(Inbox(), DEVICE, writes)
    request = parse_input(delivery.body)
    assert isinstance(request, AppParams)
    note = request.params["NOTE"]
    assert note != EMOJI * 300 and "\ufffd\ufffd" in note and utf16_length(note) == 600


@needs_node
def test_three_phones_writing_at_once_each_get_their_own_message() -> None:
    names = ["alpha", "beta", "gamma"]
    phones = [f"/org/bluez/hci0/dev_{i}" for i in range(3)] + [None]
    writes = [phone_writes([{"type": "app_params",
                             "contents": {"app": name, "params": {"X": name * 300}}}])
              for name in [*names, "delta"]]
    inbox = Inbox()
    got: dict[str | None, Delivery] = {}
    for step in range(max(len(w) for w in writes)):  # round robin, a write each in turn
        for phone, own in zip(phones, writes):
            if step < len(own):
                outcome = inbox.feed(phone, own[step])
                if isinstance(outcome, Delivery):
                    got[phone] = outcome
    assert set(got) == set(phones)
    for phone, name in zip(phones, [*names, "delta"]):
        assert got[phone].device == phone
        assert parse_input(got[phone].body) == AppParams(name, {"X": name * 300})


# --- the inbox's bounds -----------------------------------------------------------------

def test_a_message_past_the_limit_is_refused_and_its_tail_never_read() -> None:
    inbox = Inbox(limit=1000)
    long = json.dumps({"type": "app_update", "contents": "", "length": 0,
                       "pad": "x" * 3000}).encode()
    writes = [*split_utf8(long, 500), b"\x00"]
    outcomes = [inbox.feed(DEVICE, w) for w in writes]
    assert outcomes[2] == Refusal(DEVICE, too_long_text(1000))
    assert outcomes[:2] == [None, None] and all(o is None for o in outcomes[3:])
    good = json.dumps({"type": "app_update", "contents": "", "length": 0}).encode()
    assert inbox.feed(DEVICE, good) is None
    assert inbox.feed(DEVICE, b"\x00") == Delivery(DEVICE, good)


def test_the_limit_counts_the_body_not_its_nul() -> None:
    inbox = Inbox(limit=10)
    assert inbox.feed(DEVICE, b"0123456789\x00") == Delivery(DEVICE, b"0123456789")
    assert inbox.feed(DEVICE, b"01234") is None
    assert inbox.feed(DEVICE, b"56789") is None
    assert inbox.feed(DEVICE, b"\x00") == Delivery(DEVICE, b"0123456789")
    assert inbox.feed(DEVICE, b"0123456789A\x00") == Refusal(DEVICE, too_long_text(10))
    assert inbox.feed(DEVICE, b"next\x00") == Delivery(DEVICE, b"next")  # nothing discarded


def test_a_refused_phone_does_not_hold_up_another() -> None:
    inbox = Inbox(limit=10)
    assert isinstance(inbox.feed("/dev_A", b"x" * 11), Refusal)
    assert inbox.feed("/dev_B", b"ok\x00") == Delivery("/dev_B", b"ok")
    assert inbox.feed("/dev_A", b"tail\x00") is None


def test_the_phone_that_wrote_least_recently_loses_its_partial_message() -> None:
    inbox = Inbox(devices=2)
    inbox.feed("/dev_A", b"a1")
    inbox.feed("/dev_B", b"b1")
    inbox.feed("/dev_A", b"a2")  # A is now the most recent
    inbox.feed("/dev_C", b"c1")  # B is dropped
    assert inbox.under_way() == ["/dev_A", "/dev_C"]
    assert inbox.feed("/dev_B", b"b2\x00") == Delivery("/dev_B", b"b2")
    assert inbox.feed("/dev_A", b"\x00") == Delivery("/dev_A", b"a1a2")


def test_a_disconnected_phone_is_forgotten() -> None:
    inbox = Inbox()
    inbox.feed(DEVICE, b'{"type": "app_')
    inbox.forget(DEVICE)
    assert inbox.under_way() == []
    assert inbox.feed(DEVICE, b"{}\x00") == Delivery(DEVICE, b"{}")


def test_writes_without_a_device_share_a_buffer_of_their_own() -> None:
    inbox = Inbox()
    assert inbox.feed(None, b"ab") is None
    assert inbox.feed(DEVICE, b"xy\x00") == Delivery(DEVICE, b"xy")
    assert inbox.feed(None, b"c\x00") == Delivery(None, b"abc")


def test_a_nul_ending_the_last_chunk_ends_the_message_as_in_bluezone() -> None:
    """And a NUL inside a write stays in the body, where parsing refuses it."""
    inbox = Inbox()
    assert inbox.feed(DEVICE, b"") is None
    assert inbox.feed(DEVICE, b"abc\x00") == Delivery(DEVICE, b"abc")
    assert inbox.feed(DEVICE, b"a\x00b") is None  # a NUL inside a write: parsing refuses it
    assert inbox.feed(DEVICE, b"\x00") == Delivery(DEVICE, b"a\x00b")


@settings(max_examples=200, deadline=None)
@given(data=st.data(),
       text=st.text(st.characters(codec="utf-8", exclude_characters="\x00"), min_size=1,
                    max_size=2000),
       cuts=st.lists(st.integers(min_value=0, max_value=10_000), max_size=20))
def test_any_cut_of_two_interleaved_messages_is_put_together(
        data: st.DataObject, text: str, cuts: list[int]) -> None:
    """Bodies are JSON, which never holds a NUL byte; BlueZ may cut them anywhere."""
    first = text.encode("utf-8")
    second = text[::-1].encode("utf-8")

    def pieces(body: bytes) -> list[bytes]:
        points = sorted({c % len(body) for c in cuts} - {0})
        edges = [0, *points, len(body)]
        return [body[a:b] for a, b in zip(edges, edges[1:])] + [b"\x00"]

    queues = {"/dev_1": pieces(first), "/dev_2": pieces(second)}
    inbox = Inbox()
    got = {}
    while any(queues.values()):
        device = data.draw(st.sampled_from(sorted(d for d, q in queues.items() if q)))
        outcome = inbox.feed(device, queues[device].pop(0))
        if outcome is not None:
            assert isinstance(outcome, Delivery)
            got[device] = outcome.body
    assert got == {"/dev_1": first, "/dev_2": second}


# --- status -----------------------------------------------------------------------------

def test_a_status_is_its_text_in_utf8_without_a_nul() -> None:
    assert encode_status("App command success!") == b"App command success!"
    text = f"Error enabling app {CJK}: no"
    assert encode_status(text) == text.encode()


def test_a_long_or_multiline_status_is_one_line_within_a_notification() -> None:
    data = encode_status("Error adding repository: fatal:\n" + CJK * 400 + "\x1b[2J")
    assert len(data) <= STATUS_LIMIT
    text = data.decode("utf-8")  # cut at a character's start
    assert "\n" not in text and "\x1b" not in text and text.endswith("…")
