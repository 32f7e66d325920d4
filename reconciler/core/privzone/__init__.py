"""The Bluetooth protocol of Privzone, the field's phone app, as pure functions (issue 21).

libpanda's `bluezone.py` served the phone over BlueZ's GATT API; lpam serves the same phone
(docs: ../shared/reference/lpam-legacy.md, "The Bluetooth protocol the field tool speaks").
This package is the protocol's core and nothing else: how a message is cut into
notifications and put together again from writes (`framing`), what a completed message
asks for and what the phone is told (`messages`), the thermometer's text (`temperature`).
It does no I/O, holds no thread and knows no D-Bus, so that every rule of the wire can be
tested on its own, against a script that decodes exactly as the phone does
(tests/unit/privzone_phone.js). The GATT server is an adapter; running a request is the
workflow's.
"""
