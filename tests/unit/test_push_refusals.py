"""A push the repository refused (read-only for this car) told apart from a network that
failed (adapters/wire.py `refusal`): the first is asked again only at a change or the
heartbeat, the second at the next pass. The servers' words are the ones they send; the
real git daemon's are checked in tests/integration/test_fleet_scale.py."""

from __future__ import annotations

import pytest
from dulwich.client import HTTPUnauthorized
from dulwich.errors import GitProtocolError, HangupException

from reconciler.adapters.wire import refusal


@pytest.mark.parametrize("error", [
    GitProtocolError("access denied or repository not exported: /fleet.git"),  # git daemon
    GitProtocolError("service not enabled: /fleet.git"),  # git daemon --informative-errors
    HangupException([b"ERROR: Permission to our-lab/fleet-state.git denied to deploy key",
                     b"fatal: Could not read from remote repository."]),  # GitHub, ssh
    HangupException([b"remote: ", b"remote: You are not allowed to push code to this "
                     b"project."]),  # GitLab
    HangupException([b"git@github.com: Permission denied (publickey)."]),
    HTTPUnauthorized(None, "https://github.com/our-lab/fleet-state"),
    GitProtocolError("unexpected http resp 403 for https://h/fleet-state/git-receive-pack"),
    GitProtocolError("pre-receive hook declined"),
], ids=repr)
def test_a_repository_that_does_not_take_the_push_is_a_refusal(error: Exception) -> None:
    assert refusal(error)


@pytest.mark.parametrize("error", [
    ConnectionRefusedError(111, "Connection refused"),
    TimeoutError("timed out"),
    HangupException(),  # "The remote server unexpectedly closed the connection."
    OSError(-2, "Name or service not known"),
    GitProtocolError("unexpected http resp 502 for https://h/fleet-state/git-receive-pack"),
], ids=repr)
def test_a_network_that_failed_is_no_refusal(error: Exception) -> None:
    assert not refusal(error)
