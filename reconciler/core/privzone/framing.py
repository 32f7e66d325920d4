"""How a Privzone message travels: cut into notifications one way, put together from writes
the other way.

The wire, as the phone (Privzone's MapPage.js) and bluezone.py speak it:

- Pi → phone, on the output characteristic: a body
  `{"type": KIND, "contents": "<JSON text>", "length": N}`, where `contents` is itself JSON
  text and `length` is what JavaScript's `.length` says of it (UTF-16 units). It is sent in
  notifications of at most 500 characters; the last one ends in a NUL byte. The phone
  decodes *each notification on its own* (a fresh TextDecoder), concatenates the strings,
  and when a notification's last byte is 0 drops that NUL, parses the JSON and drops the
  message unless `length == contents.length`.
- phone → Pi, on the input characteristic: the same body, cut in 500 JavaScript characters,
  each chunk UTF-8 encoded and written, then a separate one-byte write of NUL.

Two things follow for the sending side, and `encode_message` does both:

1. A notification must never end inside a character. A UTF-8 sequence cut in two decodes as
   U+FFFD on both sides of the cut, the contents change and the length check drops the
   message. Cutting where the phone counts (UTF-16 units) would not be enough either: four
   bytes of UTF-8 are two units, and a cut between the halves of a surrogate pair is the
   same fault one level up.
2. A notification's value is at most 512 bytes (the largest attribute value ATT allows;
   bluetoothd cuts a longer notification to the link's MTU). bluezone's 500 characters were
   500 bytes because its JSON was ASCII; 500 characters of CJK text would be 1500.

So the body is cut at 500 *bytes* of UTF-8, backing off to the start of a character. A
character is at least as many bytes as UTF-16 units, so every notification is also at most
500 characters as the phone counts them, and with the final NUL at most 501 bytes: exactly
what bluezone sent and the phone has always received.

And the body is ASCII by default (`json.dumps`' `ensure_ascii`, as bluezone had it): every
non-ASCII character is written `\\uXXXX` (an emoji as its two surrogate escapes), which
JSON.parse turns back into the same string. Then no cut can fall inside a character at all,
Python's `len` is JavaScript's `.length` of the contents, and a string with a lone surrogate
(a file name read with `surrogateescape`) still travels; the cost is six bytes for a CJK
character instead of three, on messages of a few hundred bytes. `ascii_only=False` sends
UTF-8 instead, cut as above; the tests run both through the phone's decoding.

The receiving side is `Inbox`: one buffer per phone (bluezone shared one buffer among every
client, so two phones writing at once corrupted each other's messages), bounded in bytes
and in phones.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from reconciler.base.text import printable

NOTIFICATION_LIMIT = 500  # bytes of a notification's text, before the final NUL
END = b"\x00"  # ends a message, both ways
INPUT_LIMIT = 64 * 1024  # bytes of one phone's message; app requests are a few hundred
DEVICE_LIMIT = 32  # phones with a message under way; BlueZ links are far fewer


def utf16_length(text: str) -> int:
    """What JavaScript's `.length` says of `text`: UTF-16 code units, so a character outside
    the Basic Multilingual Plane (an emoji) counts two, where Python's `len` counts one."""
    return len(text) + sum(1 for char in text if ord(char) > 0xFFFF)


def split_utf8(data: bytes, limit: int = NOTIFICATION_LIMIT) -> list[bytes]:
    """`data` (UTF-8) cut into pieces of at most `limit` bytes, each a whole number of
    characters, so that each piece decodes on its own to exactly its characters."""
    if limit < 4:
        raise ValueError("a piece must hold a character of four bytes")
    pieces: list[bytes] = []
    start = 0
    while start < len(data):
        end = min(start + limit, len(data))
        while end < len(data) and data[end] & 0xC0 == 0x80:  # a continuation byte
            end -= 1
        pieces.append(data[start:end])
        start = end
    return pieces


def encode_message(kind: str, contents: object, *, ascii_only: bool = True,
                   limit: int = NOTIFICATION_LIMIT) -> list[bytes]:
    """The notifications that carry `contents` to the phone as a message of type `kind`.

    `contents` is anything `json.dumps` takes (NaN and infinities are refused: JSON.parse
    would reject the message). The body keeps bluezone's key order and `json.dumps`'
    default separators; the module docstring says why it is ASCII and where it is cut.
    `limit` is bluezone's 500 unless the link is known to carry less (a notification is
    at most the ATT MTU less 3 bytes, and this one grows by the final NUL): the phone
    needs no particular size, only whole characters and the NUL at the end.
    """
    text = json.dumps(contents, ensure_ascii=ascii_only, allow_nan=False)
    body = json.dumps({"type": kind, "contents": text, "length": utf16_length(text)},
                      ensure_ascii=ascii_only)
    pieces = split_utf8(body.encode("utf-8"), limit)
    pieces[-1] += END
    return pieces


STATUS_LIMIT = 500  # bytes: one notification, like the output's


def encode_status(text: str) -> bytes:
    """A status text as the one notification of the status characteristic: its UTF-8
    bytes, no NUL (bluezone sent the text's bytes as they were, and the phone decodes the
    whole value and compares it with the texts it reacts to). One line, terminal-safe, and
    cut to `STATUS_LIMIT` bytes at a character's start, ending in "…" when cut: a reason
    can echo a long git error, and a notification longer than the MTU is truncated."""
    line = printable(" ".join(text.splitlines()))
    data = line.encode("utf-8", "replace")
    if len(data) <= STATUS_LIMIT:
        return data
    ellipsis = "…".encode()
    return split_utf8(data, STATUS_LIMIT - len(ellipsis))[0] + ellipsis


@dataclass(frozen=True)
class Delivery:
    """A phone's message, complete: its body without the final NUL."""

    device: str | None
    body: bytes


@dataclass(frozen=True)
class Refusal:
    """A phone's message that was not read; `text` is the status the phone gets."""

    device: str | None
    text: str


def too_long_text(limit: int) -> str:
    return f"Upload refused: the message is longer than {limit} bytes"


@dataclass
class _Pending:
    data: bytearray = field(default_factory=bytearray)
    discarding: bool = False  # the rest of a refused message, up to its NUL


class Inbox:
    """Phone → Pi: the writes of each phone put together into messages.

    `device` is the object path BlueZ passes in WriteValue's options (None when it passes
    none: those writes share a buffer of their own). A write whose last byte is NUL ends
    the phone's message: the phone sends its NUL as a separate write, and a client that
    appends it to its last chunk is read the same way, as bluezone read it. A NUL anywhere
    else stays in the body (JSON text never holds one), and parsing refuses it.

    A message longer than `limit` bytes is refused when it passes the limit, the bytes so
    far dropped, and the phone's later writes are dropped too up to its NUL, so that the
    tail of the long message is never read as a message of its own. At most `devices`
    phones have a message under way; when another starts, the one that wrote least
    recently loses its partial message (its next write then starts a new one, which
    parsing refuses unless it is a whole message).
    """

    def __init__(self, *, limit: int = INPUT_LIMIT, devices: int = DEVICE_LIMIT) -> None:
        if limit < 1 or devices < 1:
            raise ValueError("an inbox holds at least one byte and one device")
        self.limit = limit
        self.devices = devices
        self._pending: dict[str | None, _Pending] = {}

    def feed(self, device: str | None, data: bytes) -> Delivery | Refusal | None:
        """Take one write; the completed message or its refusal, or None while it goes on."""
        if not data:
            return None
        pending = self._pending.pop(device, None) or _Pending()
        complete = data.endswith(END)
        if pending.discarding:
            if not complete:
                self._keep(device, pending)
            return None
        if len(pending.data) + len(data) - complete > self.limit:
            if not complete:
                self._keep(device, _Pending(discarding=True))
            return Refusal(device, too_long_text(self.limit))
        pending.data += data
        if complete:
            return Delivery(device, bytes(pending.data[:-1]))
        self._keep(device, pending)
        return None

    def forget(self, device: str | None) -> None:
        """Drop what `device` had sent of a message (it disconnected)."""
        self._pending.pop(device, None)

    def under_way(self) -> list[str | None]:
        """The devices with a message under way (or being dropped), least recent first."""
        return list(self._pending)

    def _keep(self, device: str | None, pending: _Pending) -> None:
        self._pending[device] = pending  # (re)inserted last: the most recent writer
        while len(self._pending) > self.devices:
            del self._pending[next(iter(self._pending))]
