"""The `Services` port on a supervisord that lpam starts for its root (developer machines,
CI, vehicles without systemd). The daemon itself — launch, socket, lock, shutdown — is
supervisor_daemon.py; the files lpam writes for it are supervisor_conf.py's.

Questions (`state`, `logs`) and `stop`/`uninstall` never start supervisord; `install` and
`start` do. A unit lpam installed while supervisord is down (after a reboot) is known and
inactive: its file is in `programs/`, and the next `start` loads it.

Definitions are applied as `supervisorctl update` does (reloadConfig, then add or replace
the process group), one unit at a time. A changed definition of a unit that is not
running takes effect at once; a running unit keeps running its old definition until its
next `start` or `restart`, which apply pending changes first (the executor stops an app
before it installs a new one, so this is the rare case of `configure`).

`start` waits for supervisord's verdict (`startsecs=1`): it returns once the program has
run for a second, and also when the program exited at once (like `systemctl start` of a
simple service: the state says so — activating while supervisord retries, then failed);
it raises when the program cannot be run at all (not found, not executable). supervisord
polls its children once a second, so a program that exits at once is sometimes taken for
one that ran past `startsecs`; it is then restarted rather than retried, and ends failed
later or keeps restarting — never reported active, so the health check fails it either way.

Orphans: a supervisord that was killed leaves its programs running, unsupervised
(orphans.py finds them by the marks every program carries). Such a unit reads as active
but not supervised; `stop` and `uninstall` end it, `start` ends it before it starts the
unit again, and a supervisord that lpam launches anew is launched only once whatever the
dead one ran is gone: never a second copy beside the first.

Restarts: supervisord does not count them, so lpam does. `start` notes where
supervisord's log ended; `state` counts the program's `spawned:` lines after that point
(following one rotation of the log); every spawn but the first is a restart. After a
reboot (the note lives in `/run`) the count starts again at 0.
"""

from __future__ import annotations

import contextlib
import os
import pwd
import time
import xmlrpc.client
from dataclasses import replace
from pathlib import Path

from supervisor.xmlrpc import Faults  # type: ignore[import-untyped]

from reconciler.adapters.services import orphans, supervisor_conf
from reconciler.adapters.services.supervisor_daemon import (
    CALL_TIMEOUT,
    POLL,
    Client,
    Down,
    connect,
    ensure,
    shutdown,
)
from reconciler.base.atomic import fsync_dir, write_atomic
from reconciler.base.errors import ServiceError
from reconciler.base.layout import Layout
from reconciler.base.reading import open_regular, tail
from reconciler.base.unit import Activity, Unit, UnitState, check_unit_name

__all__ = ["SupervisorServices", "check_user", "shutdown", "tail"]

READ_LIMIT = 1024 * 1024  # bytes of a log read for `logs` or for counting restarts

BAD_NAME: int = Faults.BAD_NAME
NO_FILE: int = Faults.NO_FILE
NOT_EXECUTABLE: int = Faults.NOT_EXECUTABLE
ABNORMAL_TERMINATION: int = Faults.ABNORMAL_TERMINATION
ALREADY_STARTED: int = Faults.ALREADY_STARTED
NOT_RUNNING: int = Faults.NOT_RUNNING
ALREADY_ADDED: int = Faults.ALREADY_ADDED
STILL_RUNNING: int = Faults.STILL_RUNNING
CANT_REREAD: int = Faults.CANT_REREAD
SPAWN_ERROR: int = Faults.SPAWN_ERROR
EXITED_AT_ONCE = "Exited too quickly"  # supervisord's spawnerr for an exit within startsecs

ACTIVITY: dict[str, Activity] = {
    "RUNNING": "active", "STARTING": "activating", "BACKOFF": "activating",
    "STOPPING": "deactivating", "STOPPED": "inactive", "EXITED": "inactive",
    "FATAL": "failed", "UNKNOWN": "unknown",
}
_ALIVE = frozenset({"STARTING", "RUNNING", "BACKOFF", "STOPPING"})


def _program(name: str) -> str:
    try:
        return check_unit_name(name)
    except ValueError as exc:
        raise ServiceError(f"unit {name!r}: {exc}") from None


class SupervisorServices:
    """The `Services` port on the supervisord of one root (see the module docstring)."""

    kind = "supervisor"

    def __init__(self, layout: Layout) -> None:
        self.layout = layout

    # -- definitions --------------------------------------------------------------

    def check(self, unit: Unit) -> None:
        """The program section renders and its user exists; supervisord is not asked."""
        name = _program(unit.name)
        self._section(unit, name)
        if unit.user is not None:
            _uid(name, unit.user)

    def _section(self, unit: Unit, name: str) -> str:
        """The program's section, its processes marked as this root's (orphans.py)."""
        log = Path(os.path.abspath(unit.log or self.layout.app_logs / f"{name}.log"))
        marked = {**unit.environment, **orphans.marks(self._conf, name)}
        return supervisor_conf.program(
            replace(unit, directory=Path(os.path.abspath(unit.directory)), environment=marked),
            name=name, log=log)

    @property
    def _conf(self) -> Path:
        return Path(os.path.abspath(self.layout.supervisor_conf))

    def install(self, unit: Unit) -> None:
        name = _program(unit.name)
        log = Path(os.path.abspath(unit.log or self.layout.app_logs / f"{name}.log"))
        text = self._section(unit, name)
        if unit.user is not None:
            _uid(name, unit.user)
        client = ensure(self.layout)
        if unit.user is not None:
            check_user(name, unit.user, manager_uid=os.stat(client.path).st_uid)
        log.parent.mkdir(parents=True, exist_ok=True)
        path = self.layout.supervisor_program(name)
        try:
            old: bytes | None = path.read_bytes()
        except FileNotFoundError:
            old = None
        write_atomic(path, text)
        try:
            diff = _reload(client)
        except ServiceError:
            # Never leave a file that stops supervisord from reading its configuration.
            if old is None:
                path.unlink(missing_ok=True)
            else:
                write_atomic(path, old)
            raise
        self._update(client, name, diff)

    def uninstall(self, name: str) -> None:
        program = _program(name)
        client = connect(self.layout)
        if client is not None:
            self._stop(client, program)
        self._end_orphans(program)
        path = self.layout.supervisor_program(program)
        if path.exists():
            path.unlink()
            fsync_dir(path.parent)
        (self.layout.supervisor_starts / program).unlink(missing_ok=True)
        if client is not None:
            try:
                client.call("removeProcessGroup", program)
            except xmlrpc.client.Fault as exc:
                if exc.faultCode != BAD_NAME:
                    raise _failed(program, "removing", exc) from None
            except Down:
                pass

    # -- actions ------------------------------------------------------------------

    def start(self, name: str) -> None:
        program = _program(name)
        client = ensure(self.layout)
        try:
            self._update(client, program, _reload(client))
            state = self._settled(client, program)
            if state is None:
                raise ServiceError(f"unit {program} is not installed in supervisord",
                                   hint="install it first (`lpam apply`)")
            if state in ("STARTING", "RUNNING", "BACKOFF"):
                return  # already started (BACKOFF: supervisord is retrying it)
            self._end_orphans(program)  # what a dead supervisord ran: never a second copy
            self._note_start(program)
            client.call("startProcess", program, True, timeout=CALL_TIMEOUT + 30)
        except xmlrpc.client.Fault as exc:
            if exc.faultCode in (ALREADY_STARTED, ABNORMAL_TERMINATION):
                return  # ABNORMAL: it ran and exited at once; `state` tells the rest
            if exc.faultCode == SPAWN_ERROR:
                # Also "it exited at once" (spawnerr says so, or is already cleared by
                # the next attempt); a fork that failed says why.
                why = self._spawn_error(client, program)
                if not why or why.startswith(EXITED_AT_ONCE):
                    return
                raise _failed(program, "starting", exc, why) from None
            raise _failed(program, "starting", exc) from None
        except Down:
            raise ServiceError(f"unit {program}: supervisord stopped while starting it",
                               hint=f"see {self.layout.supervisor_log}") from None

    def stop(self, name: str) -> None:
        """Stop it if it runs. A unit supervisord does not know is not running under it,
        which is all `stop` promises, so that is not an error."""
        program = _program(name)
        client = connect(self.layout)
        if client is not None:
            self._stop(client, program)
        self._end_orphans(program)

    def restart(self, name: str) -> None:
        self.stop(name)
        self.start(name)

    # -- questions ----------------------------------------------------------------

    def state(self, name: str) -> UnitState:
        try:
            program = check_unit_name(name)
        except ValueError:
            return UnitState(name=name, known=False)
        client = connect(self.layout)
        try:
            info = None if client is None else client.call("getProcessInfo", program)
        except xmlrpc.client.Fault as exc:
            if exc.faultCode != BAD_NAME:
                raise _failed(program, "asking the state of", exc) from None
            info = None
        except Down:
            info = None
        statename = "" if info is None else str(info.get("statename", "UNKNOWN"))
        if statename not in _ALIVE:
            left = orphans.find(self._conf, program)
            if left:  # its supervisord died (or was replaced) and left it running
                return UnitState(name=name, known=True, active="active", sub="orphaned",
                                 pid=left[0], supervised=False)
        if info is None:
            # Installed by lpam but not loaded (supervisord down after a reboot): a
            # stopped unit that `start` will bring up, not an unknown one.
            if self.layout.supervisor_program(program).is_file():
                return UnitState(name=name, known=True, active="inactive", sub="stopped")
            return UnitState(name=name, known=False)
        pid = int(info.get("pid") or 0)
        return UnitState(
            name=name, known=True, active=ACTIVITY.get(statename, "unknown"),
            sub=statename.lower(), restarts=self._restarts(program),
            pid=pid if pid > 0 else None,
        )

    def logs(self, name: str, lines: int = 20) -> list[str]:
        try:
            program = check_unit_name(name)
        except ValueError:
            return []
        log = self._setting(program, "stdout_logfile")
        path = Path(log) if log else self.layout.app_logs / f"{program}.log"
        return tail(path, max(lines, 0))

    # -- inside -------------------------------------------------------------------

    def _end_orphans(self, program: str) -> None:
        """End what a dead supervisord left running of `program` (orphans.py)."""
        left = orphans.end(orphans.find(self._conf, program),
                           wait=self._stop_seconds(program))
        if left:
            raise ServiceError(f"unit {program}: processes {left} that a dead supervisord "
                               "left running do not end, even when killed",
                               hint="see `ps -o pid,stat,cmd -p PID`; lpam starts no second "
                               "copy beside them")

    def _setting(self, program: str, key: str) -> str | None:
        try:
            text = self.layout.supervisor_program(program).read_text(errors="replace")
        except OSError:
            return None
        return supervisor_conf.settings(text).get(key)

    def _update(self, client: Client, program: str,
                diff: tuple[list[str], list[str], list[str]]) -> None:
        """Load this unit's current definition, as `supervisorctl update` does for all."""
        added, changed, removed = diff
        try:
            if program in added:
                client.call("addProcessGroup", program)
            elif program in changed or program in removed:
                if self._statename(client, program) in _ALIVE:
                    return  # running: its new definition waits for its next start
                client.call("removeProcessGroup", program)
                if program in changed:
                    client.call("addProcessGroup", program)
        except xmlrpc.client.Fault as exc:
            if exc.faultCode not in (ALREADY_ADDED, BAD_NAME, STILL_RUNNING):
                raise _failed(program, "loading", exc) from None

    def _statename(self, client: Client, program: str) -> str | None:
        try:
            return str(client.call("getProcessInfo", program)["statename"])
        except xmlrpc.client.Fault as exc:
            if exc.faultCode == BAD_NAME:
                return None
            raise

    def _spawn_error(self, client: Client, program: str) -> str:
        with contextlib.suppress(Down, xmlrpc.client.Fault):
            return str(client.call("getProcessInfo", program).get("spawnerr") or "")
        return ""

    def _settled(self, client: Client, program: str) -> str | None:
        """Its state once any stop under way has finished (bounded by its stop time)."""
        deadline = time.monotonic() + self._stop_seconds(program) + 10
        while True:
            state = self._statename(client, program)
            if state != "STOPPING" or time.monotonic() >= deadline:
                return state
            time.sleep(POLL)

    def _stop_seconds(self, program: str) -> float:
        value = self._setting(program, "stopwaitsecs")
        return float(value) if value and value.isdigit() else 10.0

    def _stop(self, client: Client, program: str) -> None:
        try:
            client.call("stopProcess", program, True,
                        timeout=self._stop_seconds(program) + 30)
        except xmlrpc.client.Fault as exc:
            if exc.faultCode == BAD_NAME:
                return
            if exc.faultCode != NOT_RUNNING:
                raise _failed(program, "stopping", exc) from None
        except Down:
            return  # supervisord went away, and its programs with it
        with contextlib.suppress(Down):
            if self._settled(client, program) == "STOPPING":
                raise ServiceError(f"unit {program} is still stopping",
                                   hint=f"see {self.layout.supervisor_log}")

    def _note_start(self, program: str) -> None:
        try:
            info = os.stat(self.layout.supervisor_log)
            mark = f"{info.st_ino} {info.st_size}\n"
        except FileNotFoundError:
            mark = "0 0\n"
        write_atomic(self.layout.supervisor_starts / program, mark)

    def _restarts(self, program: str) -> int:
        try:
            ino_text, offset_text = (self.layout.supervisor_starts / program).read_text().split()
            ino, offset = int(ino_text), int(offset_text)
        except (OSError, ValueError):
            return 0
        log = self.layout.supervisor_log
        text = ""
        try:
            current = os.stat(log)
        except FileNotFoundError:
            return 0
        if current.st_ino == ino and current.st_size >= offset:
            text = _read_from(log, offset)
        else:
            rotated = log.with_name(log.name + ".1")
            with contextlib.suppress(OSError):
                if os.stat(rotated).st_ino == ino:
                    text = _read_from(rotated, offset)
            text += _read_from(log, 0)
        return max(text.count(f"spawned: '{program}' with pid ") - 1, 0)


def _reload(client: Client) -> tuple[list[str], list[str], list[str]]:
    try:
        added, changed, removed = client.call("reloadConfig")[0]
    except xmlrpc.client.Fault as exc:
        if exc.faultCode == CANT_REREAD:
            raise ServiceError(f"supervisord cannot read its configuration: "
                               f"{exc.faultString}",
                               hint="fix or remove the file it names") from None
        raise ServiceError(f"supervisord refused to reload: {exc.faultString}") from None
    except Down:
        raise ServiceError("supervisord stopped while lpam talked to it") from None
    return list(added), list(changed), list(removed)


def _failed(program: str, doing: str, exc: xmlrpc.client.Fault, why: str = "") \
        -> ServiceError:
    code = exc.faultCode
    if code == SPAWN_ERROR:
        return ServiceError(f"unit {program} could not be started: {why or exc.faultString}",
                            hint="see `lpam logs` and the supervisord log under var/log/lpam")
    if code == BAD_NAME:
        return ServiceError(f"unit {program} is not installed in supervisord",
                            hint="install it first (`lpam apply`)")
    if code in (NO_FILE, NOT_EXECUTABLE):
        detail = exc.faultString.split(":", 1)[-1].strip()
        return ServiceError(f"unit {program} cannot be started: {detail}",
                            hint="check the app's command and that its program is executable")
    return ServiceError(f"{doing} unit {program} failed: supervisord says {exc.faultString}",
                        hint="see `lpam logs` and the supervisord log under var/log/lpam")


def _uid(unit: str, user: str) -> int:
    """The uid of `user` (a name or a number); ServiceError when it does not exist."""
    try:
        return pwd.getpwuid(int(user)).pw_uid if user.isdigit() else pwd.getpwnam(user).pw_uid
    except KeyError:
        raise ServiceError(f"unit {unit}: user {user!r} does not exist on this machine",
                           hint="create the user or change the app's `user`") from None


def check_user(unit: str, user: str, *, manager_uid: int) -> None:
    """supervisord switches to another user only when it runs as root."""
    uid = _uid(unit, user)
    if manager_uid != 0 and uid != manager_uid:
        raise ServiceError(
            f"unit {unit}: cannot run as user {user!r}: supervisord runs as uid "
            f"{manager_uid}, not root, and only root can switch users",
            hint="run lpam (and so its supervisord) as root, or drop the app's `user`",
        )


def _read_from(path: Path, offset: int) -> str:
    """The text of `path` from `offset` on, at most READ_LIMIT bytes (the last ones)."""
    fd = open_regular(path)
    if fd is None:
        return ""
    try:
        size = os.fstat(fd).st_size
        start = max(offset, size - READ_LIMIT, 0)
        return os.pread(fd, size - start, start).decode(errors="replace") if size > start \
            else ""
    finally:
        os.close(fd)
