"""A phone as Privzone is one, over the bluetoothd double (tests/bluez_double.py).

It reads and writes the way Privzone's MapPage.js does, written here from reading it:

- each output notification is decoded on its own (a fresh decoder: a character split
  between two notifications would arrive as U+FFFD) and appended; a notification whose
  last byte is NUL ends a message, the NUL dropped; the message is JSON whose `length`
  must equal the length of `contents` as JavaScript counts it (UTF-16 units), else it is
  dropped; `contents` is itself JSON;
- a message to the Pi is the same JSON, cut in 500 JavaScript characters, each written to
  the input characteristic, then a separate one-byte NUL write;
- commands are written as text to the command characteristic; status texts arrive one
  notification each.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

from tests.bluez_double import BluezDouble, until

TEMPERATURE = "00000002-710e-4a5b-8d75-3e5b444bc3cf"
OUTPUT, COMMAND, CONFIG, INPUT, STATUS = (
    f"0000000{n}-4d3d-3d3d-3d3d-3d3d3d3d3d3d" for n in (2, 3, 4, 5, 6))
CHUNK = 500  # JavaScript characters per write


def js_length(text: str) -> int:
    return len(text.encode("utf-16-le")) // 2


def js_chunks(text: str, size: int = CHUNK) -> list[str]:
    """`text` cut every `size` UTF-16 units, as `substring` cuts (a pair may split)."""
    units = text.encode("utf-16-le")
    return [units[i:i + 2 * size].decode("utf-16-le", "replace")
            for i in range(0, len(units), 2 * size)]


class Phone:
    """One phone (`device`, a BlueZ device path) talking to the car through `double`."""

    def __init__(self, double: BluezDouble, device: str) -> None:
        self.double, self.device = double, device

    async def connect(self) -> None:
        for uuid in (TEMPERATURE, STATUS, OUTPUT):
            await self.double.start_notify(uuid)

    def notified(self, uuid: str) -> list[bytes]:
        return list(self.double.notifications.get(uuid, []))

    def statuses(self) -> list[str]:
        return [value.decode("utf-8", "replace") for value in self.notified(STATUS)]

    def messages(self) -> list[tuple[str, Any]]:
        """Every complete output message the phone accepted: (type, contents)."""
        found, text = [], ""
        for value in self.notified(OUTPUT):
            text += value.decode("utf-8", "replace")
            if value[-1:] != b"\x00":
                continue
            body, text = text[:-1], ""
            message = json.loads(body)
            if message["length"] == js_length(message["contents"]):
                found.append((message["type"], json.loads(message["contents"])))
        return found

    async def command(self, text: str) -> None:
        await self.double.write(COMMAND, text.encode("utf-8"), self.device)

    async def send(self, kind: str, contents: Any) -> None:
        inner = json.dumps(contents)
        text = json.dumps({"type": kind, "contents": inner, "length": js_length(inner)})
        for piece in js_chunks(text):
            await self.double.write(INPUT, piece.encode("utf-8", "surrogatepass"),
                                    self.device)
        await self.double.write(INPUT, b"\x00", self.device)

    async def next_status(self, seen: int, timeout: float) -> str:
        """The first status text after the `seen` first ones."""
        await until(lambda: len(self.notified(STATUS)) > seen, timeout)
        return self.statuses()[seen]

    async def next_message(self, seen: int, timeout: float) -> tuple[str, Any]:
        await until(lambda: len(self.messages()) > seen, timeout)
        return self.messages()[seen]


async def settle() -> None:
    await asyncio.sleep(0.05)
