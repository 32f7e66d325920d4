"""What systemd says of a unit, parsed: the pure half of the systemd state probe.

The systemd adapter (reconciler/adapters/services/systemd.py) runs

    systemctl show --property=LoadState,ActiveState,SubState,NRestarts,MainPID -- NAME.service

and hands its output here. The format is systemctl's "show" format, one `KEY=VALUE` per
line, values unquoted and possibly containing `=`, properties in the order of systemd's
D-Bus interfaces (not the order asked for). Fixtures of each shape are in
tests/fixtures/systemctl/.

systemd answers for any name, known or not: a unit without a definition has
`LoadState=not-found` (and still `ActiveState=inactive`), which is `UnitState(name,
known=False)`, exactly as the other backends report a unit they do not know.
`NRestarts` exists since systemd 235 (Ubuntu 18.04 ships 237, but Debian 9 ships 232), so
a missing one counts as no restarts rather than as an error.
"""

from __future__ import annotations

from typing import cast, get_args

from reconciler.base.unit import Activity, UnitState

SHOW_PROPERTIES = ("LoadState", "ActiveState", "SubState", "NRestarts", "MainPID")

_ACTIVITIES: frozenset[str] = frozenset(get_args(Activity))
# Still running the same program while it re-reads its configuration.
_ALIASES = {"reloading": "active", "refreshing": "active"}


def parse_properties(text: str) -> dict[str, str]:
    """`KEY=VALUE` lines as a dict; the first `=` splits (values may hold more)."""
    pairs = (line.partition("=") for line in text.splitlines())
    return {key.strip(): value.strip() for key, sep, value in pairs if sep and key.strip()}


def parse_show(name: str, text: str) -> UnitState:
    """The state of unit `name` from `systemctl show --property=...` output.

    Raises ValueError when the text is not such output at all (no LoadState): that is a
    broken systemctl, not an unknown unit, and must not pass for "not running"."""
    props = parse_properties(text)
    load = props.get("LoadState")
    if not load:
        raise ValueError(f"no LoadState in systemctl show output for {name}: {text[:200]!r}")
    if load == "not-found":
        # As every backend reports a unit it has no definition of, whatever else systemd
        # says of it (a unit whose file was removed while it ran may still be running, but
        # lpam cannot manage what systemd has no definition of).
        return UnitState(name=name, known=False)
    raw = props.get("ActiveState", "")
    active = _ALIASES.get(raw, raw)
    return UnitState(
        name=name,
        known=True,
        active=cast(Activity, active) if active in _ACTIVITIES else "unknown",
        sub=props.get("SubState", ""),
        restarts=_number(props.get("NRestarts")) or 0,
        pid=_number(props.get("MainPID")) or None,
    )


def _number(value: str | None) -> int | None:
    """A non-negative count or PID; None when absent or not a number (`[not set]`)."""
    if value is None or not (value.isascii() and value.isdigit()):
        return None
    return int(value)
