"""The defaults every caller of the use cases shares (the CLI's flags, the agent, the
Bluetooth service, the shim), written once so a caller that omits an option gets what
`lpam` would have done."""

from __future__ import annotations

LOCK_TIMEOUT = 10.0
"""Seconds an apply, a plan or an operator command waits for a running apply to finish."""

FETCH_LOCK_TIMEOUT = 60.0
"""Seconds a fetch into the store (sync, pin, bundle) waits: it runs unattended or beside
an operator's apply, and a fetch is worth waiting for."""

SCRIPT_TIMEOUT = 600.0
"""Seconds an app script may run before it is killed."""
