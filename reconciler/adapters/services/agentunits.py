"""The systemd units that make a vehicle follow its desired-state repository (pure text).

- `lpam-agent.service` runs `lpam agent` after the network is configured
  (`network-online.target`, wanted, not required: out of WiFi range the agent still
  starts, once the wait-online service gives up, and its passes find no network until
  then). Stopping it sends SIGTERM to lpam alone (`KillMode=mixed`): lpam stops between
  passes at once and never in the middle of a cutover, so systemd waits for that
  (`TimeoutStopSec`) before it kills what is left.
- `lpam-agent-fetch.service` does nothing at start and runs a fetch-only pass when it is
  stopped, at shutdown, before the network goes down (it is ordered after
  network-online.target, and systemd stops units in the reverse order): what WiFi brought
  at the end of a trip is then applied at the next start, with no network.

Together they replace libpanda's own update-on-boot and update-on-shutdown for apps.
"""

from __future__ import annotations

from reconciler.adapters.services.unitfile import HEADER, exec_line

AGENT = "lpam-agent"
FETCH = "lpam-agent-fetch"
STOP_SECONDS = 900  # the longest cutover lpam lets finish before systemd kills it
FETCH_SECONDS = 180


def agent_units(lpam: list[str], config: str | None = None) -> dict[str, str]:
    """Unit name (without `.service`) → file text; `lpam` is the command that runs lpam
    (an absolute program), `config` an agent.yaml other than the root's."""
    options = [] if config is None else ["--config", config]
    agent = [
        HEADER,
        "[Unit]",
        "Description=lpam agent: this vehicle follows its desired-state repository",
        "Wants=network-online.target",
        "After=network-online.target",
        "",
        "[Service]",
        "Type=simple",
        f"ExecStart={exec_line([*lpam, 'agent', *options])}",
        "Restart=on-failure",
        "RestartSec=30s",
        "KillMode=mixed",
        f"TimeoutStopSec={STOP_SECONDS}s",
        "StandardOutput=journal",
        "StandardError=journal",
        "",
        "[Install]",
        "WantedBy=multi-user.target",
    ]
    fetch = [
        HEADER,
        "[Unit]",
        "Description=lpam: fetch the desired state at shutdown, to apply at the next start",
        "Wants=network-online.target",
        "After=network-online.target",
        "",
        "[Service]",
        "Type=oneshot",
        "RemainAfterExit=yes",
        "ExecStart=/bin/true",
        f"ExecStop={exec_line([*lpam, 'sync', '--fetch-only', *options])}",
        f"TimeoutStopSec={FETCH_SECONDS}s",
        "",
        "[Install]",
        "WantedBy=multi-user.target",
    ]
    return {AGENT: "\n".join(agent) + "\n", FETCH: "\n".join(fetch) + "\n"}
