"""lpam's XML-RPC client of supervisord, against a real Unix socket that accepts and then
never answers: a hung supervisord is named as such, within the call's timeout, on every
Python (3.9's socket.timeout is not TimeoutError; 3.10's is)."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest

from reconciler.adapters.services.supervisor_daemon import Client
from reconciler.base.errors import ServiceError


def test_a_supervisord_that_never_answers_is_called_hung(tmp_path: Path) -> None:
    path = str(tmp_path / "supervisor.sock")
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as listener:
        listener.bind(path)
        listener.listen(1)  # the kernel accepts the connection; nobody ever reads it
        began = time.monotonic()
        with pytest.raises(ServiceError) as caught:
            Client(path).call("getState", timeout=0.3)
        took = time.monotonic() - began
    assert "supervisord did not answer getState within 0.3 s" in str(caught.value)
    assert "lpam services shutdown" in (caught.value.hint or "")
    assert took < 30  # bounded by the call's timeout, not left hanging
