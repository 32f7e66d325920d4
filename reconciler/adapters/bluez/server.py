"""lpam's GATT server on the system D-Bus: registered with BlueZ and kept registered.

Where it stands: the Privzone glue builds a `GattServer` with its `GattHandler` and runs it
beside lpam's workflow; this module owns the bus connection, the registration of the GATT
application (`GattManager1.RegisterApplication`) and of the advertisement
(`LEAdvertisingManager1.RegisterAdvertisement`) on the adapter, and their lifetime:

- bluetoothd absent, the adapter missing, the bus down: one log line per new reason, which
  says that it retries and when, then retries with a back-off that doubles from
  FIRST_DELAY to MAX_DELAY (a line per attempt would fill the journal of a car parked
  for a week without Bluetooth);
- bluetoothd restarted (the `org.bluez` name leaves and returns, seen by NameOwnerChanged):
  a new bluetoothd knows nothing, so both are registered again at once;
- writes that need a bonded phone (the default, shape.py `flags_for`): once the GATT
  application is registered, the adapter is made not pairable, so that phones bond only
  inside the window `lpam ble pair` opens (pairing.py); `--writes open` leaves it alone;
- stop: both unregistered (errors ignored: bluetoothd may be gone), then the bus closed.
  A stop that comes while bluetoothd works on a registration does not abandon it: the
  answer is awaited (LEAVE_TIMEOUT at most), since bluetoothd may already hold the object,
  and what it may hold is unregistered like the rest. Abandoning it left the advertisement
  registered after lpam had gone, whenever the stop came between bluetoothd taking it and
  lpam reading its answer.

It uses dbus-fast's low-level API (a message handler answering calls, `Message`), which
is the same on dbus-fast 2.x (the cars' Python 3.9) and 5.x.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

from dbus_fast import BusType, Message, MessageType, Variant
from dbus_fast.aio import MessageBus

from reconciler.adapters.bluez.devices import DEVICE_IFACE, Device, device_of
from reconciler.adapters.bluez.objects import GattHandler, Objects
from reconciler.adapters.bluez.shape import Characteristic
from reconciler.adapters.bluez.tree import ADVERTISEMENT, PROPERTIES_IFACE, ROOT
from schemas.bluetooth import Writes

BLUEZ = "org.bluez"
GATT_MANAGER = "org.bluez.GattManager1"
ADAPTER_IFACE = "org.bluez.Adapter1"
ADVERTISING_MANAGER = "org.bluez.LEAdvertisingManager1"
DBUS = "org.freedesktop.DBus"
OWNER_RULE = (f"type='signal',sender='{DBUS}',interface='{DBUS}',"
              f"member='NameOwnerChanged',arg0='{BLUEZ}'")

FIRST_DELAY = 0.5
MAX_DELAY = 10.0
# bluetoothd answers RegisterApplication only after it has read the whole tree back
CALL_TIMEOUT = 15.0
LEAVE_TIMEOUT = 2.0  # per Unregister* call on stop: bluetoothd may be hung or gone
DEVICE_TIMEOUT = 2.0  # asking bluetoothd who a phone is: its address alone after that

APPLICATION = "GATT application"
ADVERTISING = "advertisement"
# What is registered, in order: its manager on the adapter, the name in its methods
# (RegisterApplication, UnregisterApplication…) and the object registered.
_REGISTRATIONS = {APPLICATION: (GATT_MANAGER, "Application", ROOT),
                  ADVERTISING: (ADVERTISING_MANAGER, "Advertisement", ADVERTISEMENT)}

T = TypeVar("T")


class GattServer:
    """Privzone's service over BlueZ; `run` serves until its `stop` event is set."""

    def __init__(self, handler: GattHandler, *, bus_address: str | None = None,
                 adapter: str = "/org/bluez/hci0", log: Callable[[str], None] = print,
                 bug: Callable[[], str] = lambda: "(no debug log)",
                 writes: Writes = Writes.BONDED) -> None:
        """`log` writes a line of the service's log; `bug` records the traceback of a fault
        of lpam's own (called inside the `except`) and says where it went; `writes` who may
        change the car (shape.py `flags_for`: bonded phones unless told otherwise)."""
        self._address = bus_address  # None: dbus-fast reads DBUS_SYSTEM_BUS_ADDRESS
        self._adapter = adapter
        self._log = log
        self._bug = bug
        self._objects = Objects(handler, log=log, released=self._advertisement_released,
                                bug=bug, writes=writes)
        self._unpairable = writes is Writes.BONDED
        self._bus: MessageBus | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None
        self._registered: set[str] = set()
        self._asked: set[str] = set()  # registrations sent, not answered: may be held
        self._dropped: set[str] = set()  # released by bluetoothd while being asked
        self._bluez: str | None = None  # bluetoothd's unique name: the only caller served
        self._problem = ""  # the last reason logged, so a retry loop logs it once

    @property
    def registering(self) -> bool:
        """True when bluetoothd holds, or may hold, something of lpam's (what a stop
        unregisters)."""
        return bool(self._registered or self._asked)

    async def run(self, stop: asyncio.Event) -> None:
        """Connect, register, serve until `stop`; then unregister and disconnect. Never
        raises for the world's faults: they are logged and retried."""
        self._loop = asyncio.get_running_loop()
        self._wake = asyncio.Event()
        delay = _Backoff()
        while not stop.is_set():
            bus = await self._connect(stop, delay)
            if bus is None:
                await self._pause(stop, delay.next())
                continue
            delay.reset()
            try:
                await self._serve(bus, stop)
            except Exception as exc:  # a fault of ours must not end the service
                self._report(f"the Bluetooth service failed: {exc!r}; starting again "
                             f"(details in {self._bug()})")
            finally:
                await self._leave(bus, stopping=stop.is_set())
            if not stop.is_set():  # the connection was lost or failed: not in a tight loop
                await self._pause(stop, delay.next())

    def notify(self, char: Characteristic, value: bytes) -> bool:
        """Send `value` to the phones listening to `char` (call on the loop's thread).
        False when none listens or the bus is down: the value is dropped, as BLE does."""
        bus = self._bus
        msg = self._objects.notification(char, value) if bus is not None else None
        if bus is None or msg is None or not bus.connected:
            return False
        bus.send(msg).add_done_callback(_consume)
        return True

    def notify_threadsafe(self, char: Characteristic, value: bytes) -> None:
        """`notify` from any thread (lpam's workflow runs in a worker): queued on the loop
        in call order; dropped when the server is not running."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
            loop.call_soon_threadsafe(self.notify, char, value)

    def device(self, path: str | None) -> Device:
        """The phone at the BlueZ device `path` (its address, and its name when BlueZ
        knows one: devices.py), asked of bluetoothd. Call from another thread than the
        loop's (the bridge's worker): it waits for the answer, DEVICE_TIMEOUT at most;
        without one (no bus, bluetoothd gone or slow, an unknown device) the address the
        path spells is what is known."""
        loop, bus = self._loop, self._bus
        if path is None or loop is None or loop.is_closed() or bus is None:
            return device_of(path, None)
        try:
            future = asyncio.run_coroutine_threadsafe(self._device(bus, path), loop)
        except RuntimeError:  # the loop closed meanwhile
            return device_of(path, None)
        try:
            return device_of(path, future.result(DEVICE_TIMEOUT + 1))
        except Exception:  # no answer in time, the bus lost: the path still names it
            future.cancel()
            return device_of(path, None)

    async def _device(self, bus: MessageBus, path: str) -> dict[str, Any] | None:
        msg = Message(destination=BLUEZ, path=path, interface=PROPERTIES_IFACE,
                      member="GetAll", signature="s", body=[DEVICE_IFACE])
        reply = await asyncio.wait_for(bus.call(msg), DEVICE_TIMEOUT)
        if reply is None or reply.message_type is not MessageType.METHOD_RETURN:
            return None
        return {str(k): v.value for k, v in reply.body[0].items()}

    async def _connect(self, stop: asyncio.Event, delay: _Backoff) -> MessageBus | None:
        where = self._address or "the system bus"
        try:
            bus = MessageBus(bus_address=self._address, bus_type=BusType.SYSTEM)
            connected = await _first(stop, bus.connect(), CALL_TIMEOUT)
        except Exception as exc:  # no socket, refused, auth: all mean "not yet"
            self._report(f"cannot connect to {where}: {_reason(exc)}", retry=delay)
            return None
        if connected is None:
            bus.disconnect()
        return connected

    async def _serve(self, bus: MessageBus, stop: asyncio.Event) -> None:
        self._bus = bus
        self._registered.clear()
        bus.add_message_handler(self._on_message)
        await _first(stop, bus.call(_daemon_call("AddMatch", "s", [OWNER_RULE])),
                     CALL_TIMEOUT)
        owner = await _first(stop, bus.call(_daemon_call("GetNameOwner", "s", [BLUEZ])),
                             CALL_TIMEOUT)
        self._bluez = (str(owner.body[0]) if owner is not None
                       and owner.message_type is MessageType.METHOD_RETURN else None)
        gone = asyncio.ensure_future(bus.wait_for_disconnect())  # type: ignore[no-untyped-call]
        gone.add_done_callback(_consume)
        delay = _Backoff()
        try:
            while not stop.is_set() and not gone.done():
                if not self._missing():
                    await self._pause(stop, None, gone)
                elif await self._register(bus, stop, delay):
                    delay.reset()
                elif not stop.is_set():
                    await self._pause(stop, delay.next(), gone)
            if gone.done():
                self._report("the system bus connection was lost; connecting again")
        finally:
            gone.cancel()

    def _missing(self) -> list[str]:
        return [w for w in _REGISTRATIONS if w not in self._registered]

    async def _register(self, bus: MessageBus, stop: asyncio.Event, delay: _Backoff) -> bool:
        """Register what bluetoothd does not have; False on a failure (reason logged) or
        a stop. A stop does not cut a registration short (module docstring)."""
        for what in self._missing():
            if stop.is_set():
                return False
            manager, kind, path = _REGISTRATIONS[what]
            call = self._adapter_call(manager, "Register" + kind, path)
            self._asked.add(what)
            self._dropped.discard(what)
            error = await _call(bus, call, stop, CALL_TIMEOUT, grace=LEAVE_TIMEOUT)
            if error is UNANSWERED:  # stopped, and still no answer: it may be held
                return False
            self._asked.discard(what)
            if error is not None and not error.startswith("org.bluez.Error.AlreadyExists"):
                if not stop.is_set():  # a stop retries nothing
                    self._report(f"cannot register the {what} on {self._adapter}: "
                                 f"{self._explain(error)}", retry=delay)
                return False
            if what in self._dropped:  # its Release overtook our reading of the answer
                self._dropped.discard(what)
                continue  # still missing: the loop registers it again
            self._registered.add(what)
            self._problem = ""
            self._log(f"registered the {what} on {self._adapter}")
            if what == APPLICATION and self._unpairable:
                await self._not_pairable(bus, stop)
        return True

    async def _not_pairable(self, bus: MessageBus, stop: asyncio.Event) -> None:
        """Writes need a bonded phone: the adapter is made not pairable (BlueZ's default
        is pairable, and a bluetoothd that restarts is back at its default), so that a
        phone bonds only inside `lpam ble pair`'s window, whatever agent runs. A failure
        is logged, never fatal: the GATT service still refuses unbonded writes."""
        error = await _call(bus, Message(
            destination=BLUEZ, path=self._adapter, interface=PROPERTIES_IFACE, member="Set",
            signature="ssv", body=[ADAPTER_IFACE, "Pairable", Variant("b", False)]),
            stop, CALL_TIMEOUT)
        if error is None:
            self._log(f"{self._adapter} is not pairable: `lpam ble pair` opens a window")
        elif not stop.is_set():
            self._log(f"could not make {self._adapter} not pairable: "
                      f"{self._explain(error)}")

    async def _leave(self, bus: MessageBus, *, stopping: bool = False) -> None:
        """Unregister what was (or may have been) registered, then close the connection.
        On a stop, each unregistration is said: the journal shows the car left BlueZ."""
        self._bus = None
        held = self._registered | self._asked
        for what in reversed([w for w in _REGISTRATIONS if w in held]):
            manager, kind, path = _REGISTRATIONS[what]
            call = self._adapter_call(manager, "Unregister" + kind, path, options=False)
            if not bus.connected or self._bluez is None:  # gone with the bus, or bluetoothd
                continue
            error = await _call(bus, call, asyncio.Event(), LEAVE_TIMEOUT)
            if not stopping:
                continue  # errors ignored: the connection is going anyway
            if error is None:
                self._log(f"unregistered the {what} from {self._adapter}")
            elif what in self._registered:
                self._log(f"could not unregister the {what} from {self._adapter}: "
                          f"{self._explain(error)}; bluetoothd drops it as lpam leaves "
                          "the bus")
        self._registered.clear()
        self._asked.clear()
        self._objects.forget()
        bus.remove_message_handler(self._on_message)
        bus.disconnect()

    def _on_message(self, msg: Message) -> Message | None:
        if (msg.message_type is MessageType.SIGNAL and msg.member == "NameOwnerChanged"
                and msg.sender == DBUS and msg.body and msg.body[0] == BLUEZ):
            self._bluez_moved(str(msg.body[1]), str(msg.body[2]))
            return None  # dbus-fast follows name owners too: let it see the signal
        return self._objects.answer(msg, self._bluez)

    def _bluez_moved(self, left: str, arrived: str) -> None:
        """A new bluetoothd knows nothing of lpam: everything is registered again."""
        self._bluez = arrived or None
        if left:
            self._log("bluetoothd left the system bus")
            self._objects.forget()
        if arrived:
            self._log("bluetoothd is on the system bus")
        self._registered.clear()
        self._problem = ""
        if self._wake is not None:
            self._wake.set()

    def _advertisement_released(self) -> None:
        """bluetoothd dropped the advertisement. Its Release is handled as the message
        arrives, while the answer to a registration sent just before it wakes `_register`
        a step later: a Release in that gap is kept in `_dropped`, or it would be lost and
        the car would stay unadvertised while lpam believes it is registered."""
        self._registered.discard(ADVERTISING)
        if ADVERTISING in self._asked:
            self._dropped.add(ADVERTISING)
        if self._wake is not None:
            self._wake.set()

    async def _pause(self, stop: asyncio.Event, delay: float | None,
                     gone: asyncio.Future[Any] | None = None) -> None:
        """Wait `delay` seconds (None: no limit), cut short by stop, bluetoothd's return
        or arrival, or the connection's loss."""
        assert self._wake is not None
        waits: list[Awaitable[Any]] = [self._wake.wait()]
        if gone is not None:
            waits.append(asyncio.shield(gone))  # the watch outlives this pause
        await _first(stop, _any(waits), delay)
        self._wake.clear()

    def _adapter_call(self, interface: str, member: str, path: str, *,
                      options: bool = True) -> Message:
        return Message(destination=BLUEZ, path=self._adapter, interface=interface,
                       member=member, signature="oa{sv}" if options else "o",
                       body=[path, {}] if options else [path])

    def _explain(self, error: str) -> str:
        return explain(error, self._adapter)

    def _report(self, problem: str, *, retry: _Backoff | None = None) -> None:
        """Log `problem` once, until the reason changes; with `retry`, say when lpam
        tries again (each attempt is not logged: that is the back-off's point)."""
        if problem != self._problem:
            self._problem = problem
            self._log(problem if retry is None else f"{problem}; {retry.said()}")


class _Backoff:
    def __init__(self) -> None:
        self._delay = FIRST_DELAY

    def next(self) -> float:
        delay, self._delay = self._delay, min(self._delay * 2, MAX_DELAY)
        return delay

    def reset(self) -> None:
        self._delay = FIRST_DELAY

    def said(self) -> str:
        """When the next attempts come, for the one line that reports a reason."""
        if self._delay >= MAX_DELAY:
            return f"retrying every {MAX_DELAY:g} s; said again only when the reason changes"
        return (f"retrying in {self._delay:g} s, then at longer intervals up to "
                f"{MAX_DELAY:g} s; said again only when the reason changes")


def explain(error: str, adapter: str) -> str:
    """A failed call on `adapter` (`error.name: text`) in the words a user acts on."""
    name = error.split(":", 1)[0]
    if name in (f"{DBUS}.Error.ServiceUnknown", f"{DBUS}.Error.NameHasNoOwner"):
        return "bluetoothd is not running (nobody owns org.bluez on the system bus)"
    if name in (f"{DBUS}.Error.UnknownObject", f"{DBUS}.Error.UnknownMethod",
                f"{DBUS}.Error.UnknownInterface"):
        return f"bluetoothd has no adapter {adapter} (is the controller up?)"
    return error


def _daemon_call(member: str, signature: str, body: list[Any]) -> Message:
    return Message(destination=DBUS, path="/org/freedesktop/DBus", interface=DBUS,
                   member=member, signature=signature, body=body)


UNANSWERED = "(stopped before an answer came)"


async def _call(bus: MessageBus, msg: Message, stop: asyncio.Event,
                timeout: float, *, grace: float = 0.0) -> str | None:
    """None when the call succeeded, else `error.name: text` (a timeout, a lost bus).
    `stop` cuts the wait short, after `grace` seconds more for the answer: then
    UNANSWERED if none came (or None when no grace was asked: nothing to know)."""
    task: asyncio.Future[Message | None] = asyncio.ensure_future(bus.call(msg))
    try:
        await _first(stop, asyncio.shield(task), timeout)
        if not task.done() and stop.is_set() and grace:
            await asyncio.wait({task}, timeout=grace)
    finally:
        if not task.done():
            task.cancel()
    if task.cancelled():
        if stop.is_set():
            return UNANSWERED if grace else None
        return f"no answer in {timeout:g} s"
    try:
        reply = task.result()
    except Exception as exc:
        return _reason(exc)
    if reply is None:
        return "no answer"
    if reply.message_type is MessageType.ERROR:
        text = reply.body[0] if reply.body else ""
        return f"{reply.error_name}: {text}"
    return None


async def _first(stop: asyncio.Event, work: Awaitable[T], timeout: float | None) -> T | None:
    """`work`'s result, or None when `stop` is set or `timeout` passes first (`work` is
    then cancelled). Its exception is raised."""
    task = asyncio.ensure_future(work)
    stopping = asyncio.ensure_future(stop.wait())
    try:
        await asyncio.wait({task, stopping}, timeout=timeout,
                           return_when=asyncio.FIRST_COMPLETED)
    finally:
        stopping.cancel()
        if not task.done():
            task.cancel()
    if task.cancelled() or not task.done():
        return None
    return task.result()


async def _any(waits: list[Awaitable[Any]]) -> None:
    tasks = [asyncio.ensure_future(w) for w in waits]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            if not task.done():
                task.cancel()


def _consume(future: asyncio.Future[Any]) -> None:
    """Fetch a background future's exception: a lost bus is handled elsewhere."""
    if not future.cancelled():
        future.exception()


def _reason(exc: BaseException) -> str:
    if isinstance(exc, asyncio.TimeoutError):
        return "no answer in time"
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
