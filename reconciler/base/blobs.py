"""git's id of a file's content (a blob), computed without git: what tells a folder on disk
equal to one in a commit whatever its files' modes (engine/observe/adoption.py), and what the
in-memory store twin names its files by."""

from __future__ import annotations

import hashlib


def blob_id(data: bytes) -> str:
    """The id git gives a blob holding `data`."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data, usedforsecurity=False).hexdigest()
