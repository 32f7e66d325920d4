"""Who a change is recorded as (reconciler/workflow/actor.py): the user at a terminal, a
phone, the agent — as `lpam history` and status name them."""

from __future__ import annotations

import pytest

from reconciler.workflow.actor import agent, phone, user
from schemas.record import Actor


def no_terminal() -> str:
    raise OSError(6, "No such device or address")  # os.getlogin() under a service


def test_sudo_user_is_the_user_not_root() -> None:
    """A car's lpam runs under sudo: "root" would name nobody."""
    found = user("lpam", env={"SUDO_USER": "alice"}, login=lambda: "root",
                 account=lambda: "root")
    assert found.shown == "alice (lpam)"


def test_without_sudo_the_login_name_then_the_account() -> None:
    assert user("libpanda-app-manager", env={}, login=lambda: "bob",
                account=lambda: "root").shown == "bob (libpanda-app-manager)"
    assert user("lpam", env={"SUDO_USER": ""}, login=no_terminal,
                account=lambda: "carol").shown == "carol (lpam)"


def test_a_uid_without_any_name_is_still_named() -> None:
    def missing() -> str:
        raise KeyError("getpwuid(): uid not found")

    found = user("lpam", env={}, login=no_terminal, account=missing)
    assert found.id is not None and found.id.startswith("uid ")


@pytest.mark.parametrize(("actor", "said"), [
    (phone("AA:BB:CC:DD:EE:FF", "Pixel 7"), "phone AA:BB:CC:DD:EE:FF (Pixel 7)"),
    (phone("AA:BB:CC:DD:EE:FF", ""), "phone AA:BB:CC:DD:EE:FF"),
    (phone(None), "phone (address not known)"),
    (agent("0123456789abcdef0123456789abcdef01234567"), "agent (fleet revision 0123456789ab)"),
    (agent(None), "agent (local override)"),
])
def test_each_actor_is_said_as_a_user_reads_it(actor: Actor, said: str) -> None:
    assert actor.shown == said


def test_only_what_is_known_is_written() -> None:
    assert phone("AA:BB:CC:DD:EE:FF").model_dump(mode="json") == \
        {"kind": "phone", "id": "AA:BB:CC:DD:EE:FF"}
