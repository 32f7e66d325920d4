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

- `lpam-ble.service` runs `lpam ble`, the Bluetooth service of the phone app, after
  bluetoothd. It serves the same GATT service and advertisement as libpanda's bluezone,
  so the two cannot run together (the phone would find two services of one UUID):
  `Conflicts=bluezone.service` stops bluezone while it runs. A stop lets a running request
  reach a safe point, never cutting a cutover short (`TimeoutStopSec` as the agent's).
"""

from __future__ import annotations

from reconciler.adapters.services.unitfile import HEADER, exec_line
from schemas.bluetooth import Writes

AGENT = "lpam-agent"
FETCH = "lpam-agent-fetch"
STOP_SECONDS = 900  # the longest cutover lpam lets finish before systemd kills it
FETCH_SECONDS = 180
BLE = "lpam-ble"
BLUEZONE = "bluezone.service"


def agent_units(lpam: list[str], config: str | None = None) -> dict[str, str]:
    """Unit name (without `.service`) → file text; `lpam` is the command that runs lpam
    (an absolute program), `config` an agent.yaml other than the root's."""
    options = [] if config is None else ["--config", config]
    online = ["Wants=network-online.target", "After=network-online.target"]
    agent = _file("lpam agent: this vehicle follows its desired-state repository", online,
                  _long_running([*lpam, "agent", *options], restart_seconds=30))
    fetch = _file("lpam: fetch the desired state at shutdown, to apply at the next start",
                  online, [
                      "[Service]",
                      "Type=oneshot",
                      "RemainAfterExit=yes",
                      "ExecStart=/bin/true",
                      f"ExecStop={exec_line([*lpam, 'sync', '--fetch-only', *options])}",
                      f"TimeoutStopSec={FETCH_SECONDS}s",
                      "",
                      "[Install]",
                      "WantedBy=multi-user.target",
                  ])
    return {AGENT: agent, FETCH: fetch}


def ble_unit(lpam: list[str], writes: Writes = Writes.BONDED) -> dict[str, str]:
    """Unit name → file text of `lpam ble` (see the module docstring); `--writes open`
    in its command line when `writes` says any phone may change the car, else the
    command is the same as before the setting existed."""
    mode = ["--writes", str(writes)] if writes is Writes.OPEN else []
    return {BLE: _file(
        "lpam ble: the phone app's (Privzone) Bluetooth service",
        ["Wants=bluetooth.service", "After=bluetooth.service dbus.service",
         f"Conflicts={BLUEZONE}"],
        _long_running([*lpam, "ble", *mode], restart_seconds=5))}


def _file(description: str, unit: list[str], rest: list[str]) -> str:
    """A unit file of lpam's: the header line, `[Unit]` with `description` and the `unit`
    lines, then the `rest` of the sections."""
    return "\n".join([HEADER, "[Unit]", f"Description={description}", *unit, "", *rest]) + "\n"


def _long_running(command: list[str], *, restart_seconds: int) -> list[str]:
    """The service and install sections of a long-running lpam command: restarted after a
    failure, SIGTERM to lpam alone so that a cutover it runs is never cut short."""
    return [
        "[Service]",
        "Type=simple",
        f"ExecStart={exec_line(command)}",
        "Restart=on-failure",
        f"RestartSec={restart_seconds}s",
        "KillMode=mixed",
        f"TimeoutStopSec={STOP_SECONDS}s",
        "StandardOutput=journal",
        "StandardError=journal",
        "",
        "[Install]",
        "WantedBy=multi-user.target",
    ]
