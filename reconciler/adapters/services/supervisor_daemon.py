"""The supervisord of one lpam root: started when first needed, reached over XML-RPC
through its unix socket, shut down on request. The port itself is supervisor.py.

Its files: `<root>/etc/lpam/supervisor/supervisord.conf` (rewritten at each launch; the
format is supervisor_conf.py's), the socket and pid file in `<root>/run/lpam/`, its log
`<root>/var/log/lpam/supervisord.log`. It runs with a small explicit environment (its
apps inherit it, as a systemd unit gets only what its definition gives), in its own
session: Ctrl-C of lpam does not stop the apps.

Finding it: whoever answers on the socket is it. A supervisord that died leaves a socket
nobody answers on (and a pid file); the next launch replaces both. Two lpam processes
that find it missing at once take a lock file (flock) in turn, so only one launches it.
A socket path is limited to 107 bytes (less the `.<pid>` supervisord appends to a
temporary name), so a deep `--root` is refused with a clear error rather than failing
inside supervisord.
"""

from __future__ import annotations

import contextlib
import http.client
import os
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import supervisor  # type: ignore[import-untyped]
from supervisor.xmlrpc import Faults, SupervisorTransport  # type: ignore[import-untyped]

from reconciler.adapters.scripts import passed_through
from reconciler.adapters.services import orphans, supervisor_conf
from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ServiceError
from reconciler.base.flock import wait_exclusive
from reconciler.base.layout import Layout
from reconciler.base.process import alive

CALL_TIMEOUT = 10.0  # an answer to a question; starting and stopping get their own bound
LAUNCH_TIMEOUT = 10.0  # from launching supervisord to its first answer
LOCK_TIMEOUT = 30.0
POLL = 0.05
# sun_path holds 108 bytes with the final NUL, and supervisord first binds
# `<socket>.<pid>` (pids up to 4194304) before it links the real name.
SOCKET_LIMIT = 107 - len(".4194304")
SHUTDOWN_STATE: int = Faults.SHUTDOWN_STATE
ORPHAN_WAIT = 10.0  # what a dead supervisord left running gets this long to stop on TERM


class Down(Exception):
    """Nobody answers on the socket: supervisord is not running (or just died)."""


class _UnixConnection(http.client.HTTPConnection):
    """HTTP over the unix socket, with a timeout (supervisor's own connection has none,
    and a hung supervisord must not hang lpam)."""

    def __init__(self, path: str, timeout: float) -> None:
        super().__init__("localhost", timeout=timeout)
        self._path = path

    def connect(self) -> None:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self.timeout)
        try:
            sock.connect(self._path)
        except BaseException:
            sock.close()
            raise
        self.sock = sock


class Client:
    """The XML-RPC `supervisor.*` namespace of one supervisord."""

    def __init__(self, path: str) -> None:
        self.path = path

    def call(self, method: str, *args: object, timeout: float = CALL_TIMEOUT) -> Any:
        """The result, or xmlrpc.client.Fault as supervisord raised it; Down when nobody
        listens; ServiceError when it cannot be asked at all."""
        transport = SupervisorTransport(None, None, "unix://" + self.path)
        transport._get_connection = lambda: _UnixConnection(self.path, timeout)
        proxy = xmlrpc.client.ServerProxy("http://127.0.0.1", transport=transport)
        try:
            return getattr(proxy.supervisor, method)(*args)
        except xmlrpc.client.Fault:
            raise
        except (FileNotFoundError, ConnectionError) as exc:
            raise Down(str(exc)) from None
        except (socket.timeout, TimeoutError):  # one class since 3.10; not on 3.9
            raise ServiceError(
                f"supervisord did not answer {method} within {timeout:g} s on {self.path}",
                hint="it may be hung; `lpam services shutdown` stops it (its apps too)",
            ) from None
        except PermissionError:
            raise ServiceError(
                f"cannot talk to supervisord on {self.path}: permission denied",
                hint="run lpam as the user that started it (root on a vehicle)",
            ) from None
        except (OSError, http.client.HTTPException, xmlrpc.client.ProtocolError) as exc:
            raise ServiceError(f"talking to supervisord on {self.path} failed: {exc}") from None
        finally:
            transport.close()


def _socket_path(layout: Layout) -> str:
    path = os.path.abspath(layout.supervisor_socket)
    if len(os.fsencode(path)) > SOCKET_LIMIT:
        raise ServiceError(
            f"the path of supervisord's socket is {len(os.fsencode(path))} bytes long, more "
            f"than the {SOCKET_LIMIT} a unix socket allows: {path}",
            hint="use a shorter --root (or LPAM_ROOT)",
        )
    return path


def connect(layout: Layout) -> Client | None:
    """A client of the running supervisord of this root, or None when none runs."""
    path = _socket_path(layout)
    if not os.path.exists(path):
        return None
    client = Client(path)
    try:
        client.call("getState")
    except Down:
        return None
    except xmlrpc.client.Fault as exc:
        if exc.faultCode == SHUTDOWN_STATE:
            return None
        raise ServiceError(f"supervisord on {path} refused getState: {exc.faultString}") \
            from None
    return client


def _supervisord_argv(conf: str) -> list[str]:
    """The `supervisord` script of this Python, else supervisor's main run by this Python
    from where lpam imports it (which may be a PYTHONPATH that supervisord, and so every
    app, is not given)."""
    beside = Path(sys.executable).parent / "supervisord"
    if os.access(beside, os.X_OK):
        return [str(beside), "-c", conf]

    where = os.path.dirname(os.path.dirname(os.path.abspath(supervisor.__file__)))
    code = f"import sys; sys.path.insert(0, {where!r}); " \
        "from supervisor.supervisord import main; main()"
    return [sys.executable, "-c", code, "-c", conf]


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
    try:
        if not wait_exclusive(fd, timeout=LOCK_TIMEOUT, poll=POLL):
            raise ServiceError(
                f"another lpam has been starting supervisord for {LOCK_TIMEOUT:g} s "
                f"(lock {path})")
        yield
    finally:
        os.close(fd)


def _launch(layout: Layout) -> Client:
    """Write supervisord.conf, start supervisord (it daemonizes) and wait for its answer."""
    sock = _socket_path(layout)
    for folder in (layout.run_dir, layout.supervisor_programs, layout.app_logs):
        folder.mkdir(parents=True, exist_ok=True)
    conf = os.path.abspath(layout.supervisor_conf)
    write_atomic(Path(conf), supervisor_conf.supervisord(
        root=layout.root, socket=Path(sock),
        pidfile=Path(os.path.abspath(layout.supervisor_pid)),
        logfile=Path(os.path.abspath(layout.supervisor_log)),
        childlogdir=Path(os.path.abspath(layout.app_logs)),
        directory=Path(os.path.abspath(layout.run_dir)),
    ))
    hint = f"see {layout.supervisor_log} and {conf}"
    try:
        # The parent exits once the socket is bound and the daemon has forked; errors
        # (a bad configuration, a socket in use) come before that, on its output. Every
        # app inherits supervisord's environment: small and explicit, as systemd gives a
        # unit (the app's own variables come from its definition).
        done = subprocess.run(
            _supervisord_argv(conf), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, env=passed_through(), cwd=layout.run_dir,
            timeout=LAUNCH_TIMEOUT, check=False,
        )
    except subprocess.TimeoutExpired:
        raise ServiceError(f"supervisord did not start within {LAUNCH_TIMEOUT:g} s",
                           hint=hint) from None
    except OSError as exc:
        raise ServiceError(f"cannot run supervisord: {exc.strerror}",
                           hint="install the `supervisor` Python package") from None
    if done.returncode != 0:
        said = done.stdout.decode(errors="replace").strip().splitlines()
        raise ServiceError(
            f"supervisord did not start (exit code {done.returncode})"
            + (f": {said[-1]}" if said else ""), hint=hint)
    deadline = time.monotonic() + LAUNCH_TIMEOUT
    while True:
        client = connect(layout)
        if client is not None:
            with contextlib.suppress(Down, xmlrpc.client.Fault):
                if client.call("getState").get("statename") == "RUNNING":
                    return client
        if time.monotonic() >= deadline:
            raise ServiceError(
                f"supervisord started but did not answer on {sock} within "
                f"{LAUNCH_TIMEOUT:g} s", hint=hint)
        time.sleep(POLL)


def _wait_gone(pid: int, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while alive(pid):
        if time.monotonic() >= deadline:
            return False
        time.sleep(POLL)
    return True


def _pid_from_file(layout: Layout) -> int | None:
    """The pid in supervisord.pid when that process is this root's supervisord (a pid
    file outlives its process, and pids are reused)."""
    try:
        pid = int(layout.supervisor_pid.read_text().strip())
    except (OSError, ValueError):
        return None
    if pid <= 1 or not alive(pid):
        return None
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return pid  # no /proc: trust the pid file
    conf = os.fsencode(os.path.abspath(layout.supervisor_conf))
    if any(b"supervisord" in part for part in cmdline) and conf in cmdline:
        return pid
    return None


def ensure(layout: Layout) -> Client:
    """A client of this root's supervisord, launched first if none runs — once whatever a
    dead predecessor ran is gone (orphans.py): a new one starts no app beside an old copy."""
    client = connect(layout)
    if client is not None:
        return client
    with _locked(layout.supervisor_lock):
        client = connect(layout)
        if client is not None:
            return client
        left = orphans.end(orphans.find(_conf(layout)), wait=ORPHAN_WAIT)
        if left:
            raise ServiceError(
                f"processes {left} that a dead supervisord left running do not end, even "
                "when killed", hint="see `ps -o pid,stat,cmd -p PID`; lpam starts no "
                "supervisord beside them")
        return _launch(layout)


def _conf(layout: Layout) -> Path:
    return Path(os.path.abspath(layout.supervisor_conf))


def shutdown(layout: Layout, *, timeout: float = 60.0) -> bool:
    """Stop the supervisord of this root and so every app it runs; False when none ran
    and none of its apps was left running by a dead one.

    Asks it to shut down (it stops its programs, each within its stop time), waits for its
    pid to go, and kills it by pid as a last resort; then ends whatever carries its marks
    (orphans.py): what a killed supervisord — this one or an earlier one — left running."""
    ran = _shutdown(layout, timeout=timeout)
    left = orphans.find(_conf(layout))
    orphans.end(left, wait=ORPHAN_WAIT)
    return ran or bool(left)


def _shutdown(layout: Layout, *, timeout: float) -> bool:
    try:
        client = connect(layout)
    except ServiceError:
        client = None  # hung or unreachable: the pid file is the way left
    pid: int | None = None
    apps: list[int] = []
    if client is not None:
        try:
            pid = int(client.call("getPID"))
            apps = [int(i["pid"]) for i in client.call("getAllProcessInfo") if i.get("pid")]
            client.call("shutdown")
        except xmlrpc.client.Fault as exc:
            if exc.faultCode != SHUTDOWN_STATE:
                raise ServiceError(f"supervisord refused to shut down: {exc.faultString}") \
                    from None
        except (Down, ServiceError):
            pass
    if pid is None:
        pid = _pid_from_file(layout)
        if pid is None:
            return False
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    if _wait_gone(pid, timeout):
        return True
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)
    _wait_gone(pid, 5.0)
    for app in apps:  # marked or not (a program an older lpam wrote): its group
        with contextlib.suppress(OSError):
            os.killpg(app, signal.SIGKILL)
    return True

