"""Who asks for a change: the one rule every caller of the workflow goes through.

Each caller names itself and nothing more — the CLI `user("lpam")`, libpanda-app-manager
`user("libpanda-app-manager")`, the Bluetooth service `phone(address, name)`, the agent
`agent(revision)` — and passes the value in its `ApplyOptions.by`; the workflow writes it
on what the change records (schemas/record.py `Actor`: the history entries and the last
apply). So no caller decides how a user is found, and a new caller cannot record a
change under another's name by accident.

The user at a terminal is `SUDO_USER` when lpam runs under sudo (a car's lpam runs as
root: "root" would name nobody), else the login name of the terminal (`os.getlogin`),
else the account of the process's uid (a service, a cron job: no terminal). A phone is
its Bluetooth address, as BlueZ gave it with the write, and its name when BlueZ knows
one. What BlueZ refuses before lpam sees it (a write from an unbonded phone to an
`encrypt-write` characteristic) is not here: lpam records what reaches it.
"""

from __future__ import annotations

import os
import pwd
from collections.abc import Callable, Mapping

from schemas.record import Actor


def _login() -> str:
    return os.getlogin()


def _account() -> str:
    return pwd.getpwuid(os.getuid()).pw_name


def user(via: str, *, env: Mapping[str, str] | None = None,
         login: Callable[[], str] = _login, account: Callable[[], str] = _account) -> Actor:
    """The user who ran `via` (see the module docstring for the order); `login` and
    `account` are the system's, given by tests."""
    env = os.environ if env is None else env
    name = env.get("SUDO_USER") or None
    for ask in (login, account):
        if name:
            break
        try:
            name = ask() or None
        except (OSError, KeyError):  # no terminal (a service), a uid with no account
            name = None
    return Actor(kind="user", id=name or f"uid {os.getuid()}", via=via)


def phone(address: str | None, name: str | None = None) -> Actor:
    """The phone that wrote the request (None: BlueZ gave no device with the write)."""
    return Actor(kind="phone", id=address or None, name=name or None)


def agent(revision: str | None) -> Actor:
    """The agent applying the fleet's `revision` (None: the car's local override)."""
    return Actor(kind="agent", id=revision)
