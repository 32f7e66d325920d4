"""What an operator may ask of the installed app, as a closed set.

`lpam start|stop|restart` (and later the Bluetooth service and the `libpanda-app-manager`
shim) pass one of these to the workflow and the planner, which decide on it: a misspelt
action is refused where it is parsed, never silently taken for "start".
"""

from __future__ import annotations

from schemas.enums import StrEnum


class OperatorAction(StrEnum):
    """An operator command on the installed app."""

    START = "start"
    STOP = "stop"  # holds: the app stays stopped until a start or a new desired state
    RESTART = "restart"
