"""Debian's headless Chromium, for the tests that open a page lpam writes (the fleet
report): its DOM after layout (`--dump-dom`) and a screenshot at a phone's size. Every
run has its own profile and HOME under the test's folder, no network is asked for (the
page is a file), and the browser is killed if it outlives its timeout."""

from __future__ import annotations

import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import pytest

PHONE = (412, 915)
"""A phone's viewport in CSS pixels (width, height)."""

LONG = 6000
"""The height a screenshot is taken at: a phone's width, the page's whole length."""


def chromium() -> str:
    found = shutil.which("chromium")
    if found is None:
        pytest.skip("Debian's chromium is not installed (`bash scripts/dev test` installs "
                    "it when run as root)")
    return found


def _run(args: list[str], home: Path) -> str:
    home.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(
        [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
         f"--user-data-dir={home / 'profile'}", *args],
        capture_output=True, text=True, timeout=90, env={"HOME": str(home),
                                                         "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def dom(page: Path, home: Path) -> str:
    """The page's DOM as the browser built it."""
    return _run(["--dump-dom", page.resolve().as_uri()], home / "dom")


def screenshot(page: Path, home: Path, *, height: int = LONG) -> bytes:
    """A PNG of the page at a phone's width, `height` pixels down (default: the page's
    whole length)."""
    shot = home / "shot.png"
    _run([f"--screenshot={shot}", f"--window-size={PHONE[0]},{height}",
          page.resolve().as_uri()], home / "shot")
    return shot.read_bytes()


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def png_colours(data: bytes) -> set[tuple[int, int, int]]:
    """Every colour the screenshot holds (an 8-bit RGB or RGBA PNG, as Chromium writes
    it): its scanlines inflated and unfiltered (PNG's five filters), alpha dropped."""
    width, _ = png_size(data)
    depth, kind = data[24], data[25]
    assert depth == 8 and kind in (2, 6), f"a PNG of bit depth {depth}, colour type {kind}"
    size = 3 if kind == 2 else 4
    chunks, at = [], 8
    while at < len(data):
        length, name = struct.unpack(">I4s", data[at:at + 8])
        if name == b"IDAT":
            chunks.append(data[at + 8:at + 8 + length])
        at += 12 + length
    raw = zlib.decompress(b"".join(chunks))
    stride = width * size
    previous = bytearray(stride)
    found: set[tuple[int, int, int]] = set()
    for row in range(len(raw) // (stride + 1)):
        method = raw[row * (stride + 1)]
        line = bytearray(raw[row * (stride + 1) + 1:(row + 1) * (stride + 1)])
        for i in range(stride):
            left = line[i - size] if i >= size else 0
            up = previous[i]
            corner = previous[i - size] if i >= size else 0
            if method == 1:
                line[i] = (line[i] + left) & 0xFF
            elif method == 2:
                line[i] = (line[i] + up) & 0xFF
            elif method == 3:
                line[i] = (line[i] + (left + up) // 2) & 0xFF
            elif method == 4:
                guess = left + up - corner
                near = min((abs(guess - left), 0, left), (abs(guess - up), 1, up),
                           (abs(guess - corner), 2, corner))
                line[i] = (line[i] + near[2]) & 0xFF
        found.update(tuple(line[i:i + 3]) for i in range(0, stride, size))  # type: ignore[misc]
        previous = line
    return found
