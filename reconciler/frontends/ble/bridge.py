"""Between the GATT server's event loop and lpam's workflow: the phone's writes are read
at once, the work they ask for runs on one worker thread, one request at a time.

Why a worker: an apply takes minutes (a catkin build, a pip install), and the phone shows
the car as disconnected after 20 s without a temperature notification. The GATT loop
therefore never waits on lpam: `write` only parses and queues (a full queue is an error
text, not a wait), and the worker sends what a request produced through the server's
thread-safe notify. Requests run in the order they came, from any phone; each phone has its
own input buffer (privzone.framing.Inbox), so two phones' chunks never mix.

Who asked: each request runs as the phone that wrote it (`who`, from the device BlueZ
named with the write: workflow/actor.py), so history and status name that phone. The
phone is asked of BlueZ on the worker, where waiting costs the GATT loop nothing. What
the bridge itself refuses — a malformed message, a full queue — is logged with the
phone's address as the device path spells it. What BlueZ refuses before lpam (an
unbonded phone's write to an `encrypt-write` characteristic) never reaches the bridge:
BlueZ's own log has it.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Union

from reconciler.adapters.bluez.devices import address_in
from reconciler.adapters.bluez.shape import Characteristic
from reconciler.core.privzone import messages as m
from reconciler.core.privzone.framing import Delivery, Inbox, encode_status
from reconciler.frontends.ble import answers
from reconciler.frontends.ble.temperature import Thermometer
from reconciler.frontends.console import guarded
from reconciler.workflow.actor import phone
from reconciler.workflow.events import Event, Report
from reconciler.workflow.machine import Machine
from schemas.record import Actor

QUEUED = 4
"""Requests that may wait behind the one running; more are refused with a text."""

BUSY = f"Busy: {QUEUED} requests are waiting; try again when they are done"

PACE = 0.05
"""Seconds between two notifications of one message (the phone reads them in order)."""

Send = Callable[[Characteristic, bytes], None]
Who = Callable[[Union[str, None]], Actor]
Work = Union[m.Command, m.Request]


@dataclass(frozen=True)
class _Job:
    work: Work
    device: str | None


class Bridge:
    """The GATT handler (adapters/bluez GattHandler) of `lpam ble`."""

    def __init__(self, machine: Machine, send: Send, *, thermometer: Thermometer,
                 log: Callable[[str], None], bug: Callable[[], str],
                 who: Who | None = None) -> None:
        """`send` notifies a characteristic from any thread; `log` writes a line of the
        service's log; `bug` records the traceback of an unexpected error and says where;
        `who` names the phone at a BlueZ device path (called on the worker; default: the
        address the path spells)."""
        self._machine, self._send, self._log, self._bug = machine, send, log, bug
        self._who: Who = who or (lambda device: phone(address_in(device)))
        self.thermometer = thermometer
        self._inbox = Inbox()
        self._jobs: queue.Queue[_Job | None] = queue.Queue(maxsize=QUEUED)
        self._last: dict[Characteristic, bytes] = {}
        self._command = b""
        self._worker = threading.Thread(target=self._work, name="lpam-ble-worker",
                                        daemon=True)
        self._worker.start()

    # -- what the GATT server calls (on its loop: never blocks) -------------------------

    def read(self, char: Characteristic, device: str | None) -> bytes:
        if char is Characteristic.TEMPERATURE:
            return self.thermometer.reading().encode("utf-8")
        if char is Characteristic.UNIT:
            return b"F" if self.thermometer.fahrenheit else b"C"
        if char in (Characteristic.COMMAND, Characteristic.CONFIG):
            return self._command
        return self._last.get(char, b"")

    def write(self, char: Characteristic, value: bytes, device: str | None) -> None:
        if char is Characteristic.UNIT:
            self.thermometer.set_unit(value)
        elif char in (Characteristic.COMMAND, Characteristic.CONFIG):
            self._command = value[:64]
            self._parsed(lambda: m.parse_command(value), device)
        elif char is Characteristic.INPUT:
            done = self._inbox.feed(device, value)
            if isinstance(done, Delivery):
                self._parsed(lambda: m.parse_input(done.body), device)
            elif done is not None:
                self._refused(done.text, device)

    def subscribed(self, char: Characteristic, on: bool) -> None:
        if char is Characteristic.STATUS and on:
            self.status(m.Status.HELLO)

    # -- the rest -----------------------------------------------------------------------

    def status(self, text: str) -> None:
        """A status text to the phone (and what a read of the status returns)."""
        self._log(f"status: {text}")
        self._notify(Characteristic.STATUS, encode_status(text))

    def stop(self, timeout: float) -> bool:
        """Let the request running finish (at most `timeout` s); True if it did."""
        with contextlib.suppress(queue.Full):
            self._jobs.put_nowait(None)
        self._worker.join(timeout)
        return not self._worker.is_alive()

    def _parsed(self, parse: Callable[[], Work], device: str | None) -> None:
        try:
            work = parse()
        except m.ProtocolError as exc:
            self._refused(exc.text, device)
            return
        try:
            self._jobs.put_nowait(_Job(work, device))
        except queue.Full:
            self._refused(BUSY, device)

    def _refused(self, text: str, device: str | None) -> None:
        """A write the bridge refuses: logged with the phone that wrote it, said to it."""
        self._log(f"refused a write from {address_in(device) or 'an unknown phone'}")
        self.status(text)

    def _notify(self, char: Characteristic, value: bytes) -> None:
        self._last[char] = value
        self._send(char, value)

    def _work(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            # who asked: a fault in asking BlueZ must cost the name, not the service
            by = guarded(partial(self._who, job.device), bug=self._bug,
                         internal=partial(self._unnamed, job.device))
            self._log(f"request from {by.shown}: {job.work!r}")
            # a bug must not end the service: said to the phone, and logged
            answer = guarded(partial(self._answer, job.work, by), bug=self._bug,
                             internal=partial(self._internal, job.work))
            for index, chunk in enumerate(answer.output):
                if index:
                    time.sleep(PACE)
                self._notify(Characteristic.OUTPUT, chunk)
            if answer.status is not None:
                self.status(answer.status)

    def _unnamed(self, device: str | None, exc: Exception, where: str) -> Actor:
        """The phone at `device` by the address its path spells, when asking BlueZ failed
        for a fault of lpam's (logged: its traceback is in `where`)."""
        self._log(f"internal error naming the phone at {device}: {exc!r}; details in "
                  f"{where}")
        return phone(address_in(device))

    def _internal(self, work: Work, exc: Exception, where: str) -> answers.Answer:
        self._log(f"internal error on {work!r}: {exc!r}; details in {where}")
        return answers.Answer(status=f"Internal error in lpam ({type(exc).__name__}); "
                              "details in its debug log")

    def _answer(self, work: Work, by: Actor) -> answers.Answer:
        report: Report = self._report
        if isinstance(work, m.Command):
            return answers.command(self._machine, work, report, by=by)
        return answers.request(self._machine, work, report, by=by)

    def _report(self, event: Event) -> None:
        text = getattr(event, "text", None) or getattr(event, "line", None)
        if text:
            self._log(f"  {text}")
