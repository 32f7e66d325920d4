"""`lpam ble`: register with BlueZ, serve phones until SIGTERM or Ctrl-C, unregister.

The loop does three things and waits on none of them: the GATT server (D-Bus, with
re-registration when bluetoothd restarts), the temperature every `TICK` seconds, and the
phones' writes, which go to the bridge's worker. A stop (SIGTERM from systemd, Ctrl-C)
unregisters both objects at once, so the phone sees the car leave, and then lets a request
that is running end at its next safe point — never in the middle of a cutover, as the
agent's stop (the machine's `stop_requested`).

A stop that comes before the loop has its handlers (while lpam starts) is kept by the
caller's `stopping` event and acted on as soon as the loop runs: nothing is registered
then, and the log says so rather than "unregistering".
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import threading
from collections.abc import Callable
from dataclasses import replace

from reconciler.adapters.bluez.server import GattServer
from reconciler.adapters.bluez.shape import Characteristic
from reconciler.frontends.ble.bridge import Bridge
from reconciler.frontends.ble.temperature import Thermometer
from reconciler.workflow.actor import phone
from reconciler.workflow.bluetooth import announced, said
from reconciler.workflow.machine import Machine
from schemas.bluetooth import Writes
from schemas.record import Actor

TICK = 1.0
"""Seconds between two temperatures (the phone gives up after 20 s without one)."""

STOP_WAIT = 900.0
"""Seconds a stop waits for the request running to reach a safe point (the unit's
TimeoutStopSec is the same: adapters/services/agentunits.py)."""


def serve(machine: Machine, *, bus_address: str | None, adapter: str,
          log: Callable[[str], None], bug: Callable[[], str],
          stopping: threading.Event | None = None, writes: Writes = Writes.BONDED) -> int:
    """Run until stopped; 0 when stopped by a signal, as a service should. `stopping`:
    set by the caller's own signal handlers while lpam was starting; `writes`: who may
    change the car (recorded for `lpam status` while it runs)."""
    stopping = threading.Event() if stopping is None else stopping
    machine = replace(machine, stop_requested=stopping.is_set)
    log(said(writes))
    with announced(machine.layout, writes=writes, adapter=adapter,
                   since=machine.clock().isoformat(timespec="seconds")):
        asyncio.run(_serve(machine, stopping, bus_address=bus_address, adapter=adapter,
                           log=log, bug=bug, writes=writes))
    return 0


async def _serve(machine: Machine, stopping: threading.Event, *, bus_address: str | None,
                 adapter: str, log: Callable[[str], None], bug: Callable[[], str],
                 writes: Writes) -> None:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    servers: list[GattServer] = []

    def on_signal() -> None:
        if stop.is_set():
            return
        registered = bool(servers) and servers[0].registering
        log("stopping: unregistering from BlueZ" if registered else
            "stopping: nothing was registered with BlueZ")
        stopping.set()
        stop.set()

    def who(device: str | None) -> Actor:
        """The phone at `device`, as bluetoothd knows it (asked on the bridge's worker)."""
        found = servers[0].device(device)
        return phone(found.address, found.name)

    thermometer = Thermometer(machine.layout.thermal_zone)
    bridge = Bridge(machine, lambda char, value: servers[0].notify_threadsafe(char, value),
                    thermometer=thermometer, log=log, bug=bug, who=who)
    server = GattServer(bridge, bus_address=bus_address, adapter=adapter, log=log, bug=bug,
                        writes=writes)
    servers.append(server)
    for number in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(number, on_signal)
    if stopping.is_set():  # a signal while lpam started, before these handlers
        on_signal()
    ticking = asyncio.ensure_future(_tick(server, thermometer, stop))
    try:
        await server.run(stop)
    finally:
        stop.set()
        await ticking
    if not await loop.run_in_executor(None, bridge.stop, STOP_WAIT):
        log(f"a request was still running after {STOP_WAIT:g} s; leaving it to the next "
            "`lpam apply`, which resumes it")


async def _tick(server: GattServer, thermometer: Thermometer, stop: asyncio.Event) -> None:
    while not stop.is_set():
        server.notify(Characteristic.TEMPERATURE, thermometer.reading().encode("utf-8"))
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(stop.wait(), TICK)
