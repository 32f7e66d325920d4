"""One contract for every service manager lpam drives: a real supervisord started under
the test's temporary root (SupervisorServices) and the in-memory twin (MemoryServices).

What the executor relies on — install/uninstall idempotent, start gives a running unit
with a pid, stop and restart act now, an unknown unit is `known=False` and cannot be
started, a unit that dies at once is never reported active — is written once for both.
What only a real process manager can show (a stop reaches the whole process group, argv
and environment arrive byte for byte, one supervisord per root that outlives lpam and is
restarted when it died) is checked against supervisord alone.

Every supervisord a test starts, and every process it ran, is stopped by pid at teardown,
whatever the test did; nothing is written outside the test's temporary folder, and the
only socket is a unix socket there.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from supervisor.options import ServerOptions  # type: ignore[import-untyped]

from reconciler.adapters.services import supervisor_conf
from reconciler.adapters.services.memory import MemoryServices
from reconciler.adapters.services.supervisor import SupervisorServices, check_user, shutdown
from reconciler.base.errors import ServiceError
from reconciler.base.layout import Layout
from reconciler.base.unit import Unit, UnitState
from reconciler.engine.execution.ports import Services

NAME = "lpam-app-alpha"
PY = sys.executable
SLEEPER = (PY, "-c", "import time; print('up', flush=True); time.sleep(60)")
CRASHER = (PY, "-c", "raise SystemExit(3)")
PRINTER = (PY, "-c", "print('line 1'); print('line 2'); print('line 3', flush=True); "
           "import time; time.sleep(60)")
# Writes its arguments, or the environment variables its arguments name, to a file.
ARGV_DUMP = "import json, sys, time; open('argv.json', 'w').write(json.dumps(sys.argv[1:])); " \
    "time.sleep(60)"
ENV_DUMP = "import json, os, sys, time; open('env.json', 'w').write(json.dumps(" \
    "{k: os.environ.get(k) for k in sys.argv[1:]})); time.sleep(60)"

AWKWARD = [
    "two words", "it's", '"double"', "100%", "%(here)s", "%(ENV_HOME)s", "%%", "a ;b",
    "x\t#y", "#hash", ";", "", "back\\slash", "$HOME", "*", "café", "'", "a=b,c",
]


def wait_for(check: Callable[[], bool], seconds: float = 8.0) -> bool:
    deadline = time.monotonic() + seconds
    while not check():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)
    return True


def alive(pid: int) -> bool:
    """Running, and not a zombie (PID 1 of these machines does not always reap)."""
    try:
        os.kill(pid, 0)
        fields = Path(f"/proc/{pid}/stat").read_text()
    except (ProcessLookupError, FileNotFoundError):
        return False
    return fields.rsplit(")", 1)[-1].split()[0] != "Z"


def _proc(pid: str) -> tuple[int, list[bytes]] | None:
    """(parent pid, command line) of a process, None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[-1].split()
    return (int(fields[1]), cmdline) if fields[0] != "Z" else None


def supervisords(layout: Layout) -> list[int]:
    """Every live supervisord started with this root's configuration."""
    conf = os.fsencode(os.path.abspath(layout.supervisor_conf))
    found = []
    for entry in os.listdir("/proc"):
        info = _proc(entry) if entry.isdigit() else None
        if info is not None and conf in info[1] and any(b"supervisord" in p for p in info[1]):
            found.append(int(entry))
    return found


def children(parents: list[int]) -> list[int]:
    found = []
    for entry in os.listdir("/proc"):
        info = _proc(entry) if entry.isdigit() else None
        if info is not None and info[0] in parents:
            found.append(int(entry))
    return found


def reap(layout: Layout) -> None:
    """Stop by pid every supervisord of this root and every program they ran."""
    daemons = supervisords(layout)
    apps = children(daemons)
    with contextlib.suppress(Exception):
        shutdown(layout, timeout=15)
    for pid in daemons:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    for pid in apps:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pid, signal.SIGKILL)


def kill(pid: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)


@dataclass
class World:
    """A service manager and how to make its programs misbehave."""

    services: Services
    root: Path
    real: bool
    crashes: Callable[[str], None]  # the unit's program exits at once
    refuses: Callable[[str], None]  # the unit's program cannot be run at all
    prints: Callable[[str, list[str]], None]  # what the unit's program printed

    def unit(self, name: str = NAME, argv: tuple[str, ...] = SLEEPER, **kwargs: Any) -> Unit:
        folder = self.root / "app"
        folder.mkdir(exist_ok=True)
        return Unit(name=name, argv=argv, directory=folder, stop_seconds=5, **kwargs)


def _memory(tmp_path: Path) -> Iterator[World]:
    twin = MemoryServices()
    yield World(twin, tmp_path, False, twin.crash_on_start.add, twin.refuse_start.add,
                lambda name, lines: twin.output.__setitem__(name, lines))


def _supervisor(tmp_path: Path) -> Iterator[World]:
    layout = Layout(tmp_path)
    try:
        yield World(SupervisorServices(layout), tmp_path, True, lambda name: None,
                    lambda name: None, lambda name, lines: None)
    finally:
        reap(layout)


@pytest.fixture(params=[_supervisor, _memory], ids=["supervisor", "memory"])
def world(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[World]:
    yield from request.param(tmp_path)


@pytest.fixture
def sv(tmp_path: Path) -> Iterator[World]:
    yield from _supervisor(tmp_path)


# -- the contract -----------------------------------------------------------------------


def test_install_then_start_runs_it_with_a_pid(world: World) -> None:
    world.services.install(world.unit())
    installed = world.services.state(NAME)
    assert installed.known and installed.active == "inactive" and installed.pid is None
    world.services.start(NAME)
    state = world.services.state(NAME)
    assert state.running and state.known and state.active == "active"
    assert state.pid is not None and state.pid > 0
    assert not world.real or alive(state.pid)
    world.services.start(NAME)  # already running: nothing happens
    assert world.services.state(NAME).pid == state.pid


def test_stop_makes_it_inactive_and_is_idempotent(world: World) -> None:
    world.services.install(world.unit())
    world.services.start(NAME)
    pid = world.services.state(NAME).pid
    assert pid is not None
    world.services.stop(NAME)
    state = world.services.state(NAME)
    assert state.known and state.active == "inactive" and state.pid is None
    assert not world.real or not alive(pid)
    world.services.stop(NAME)
    world.services.stop("lpam-app-never-installed")  # nothing by that name runs


def test_restart_runs_a_new_process(world: World) -> None:
    world.services.install(world.unit())
    world.services.start(NAME)
    first = world.services.state(NAME).pid
    world.services.restart(NAME)
    state = world.services.state(NAME)
    assert state.running and state.pid is not None and state.pid != first
    assert not world.real or (alive(state.pid) and first is not None and not alive(first))
    world.services.stop(NAME)
    world.services.restart(NAME)  # a stopped unit is started
    assert world.services.state(NAME).running


def test_uninstall_stops_and_removes_it_and_is_idempotent(world: World) -> None:
    world.services.install(world.unit())
    world.services.start(NAME)
    pid = world.services.state(NAME).pid
    assert pid is not None
    world.services.uninstall(NAME)
    assert world.services.state(NAME) == UnitState(NAME, known=False)
    assert not world.real or not alive(pid)
    world.services.uninstall(NAME)
    world.services.uninstall("lpam-app-never-installed")
    with pytest.raises(ServiceError, match=NAME):
        world.services.start(NAME)


def test_an_unknown_unit_is_not_known_and_cannot_be_started(world: World) -> None:
    assert world.services.state("lpam-app-nobody") == UnitState("lpam-app-nobody", known=False)
    assert world.services.logs("lpam-app-nobody") == []
    with pytest.raises(ServiceError, match="lpam-app-nobody"):
        world.services.start("lpam-app-nobody")


def test_a_program_that_cannot_run_is_a_service_error_naming_the_unit(world: World) -> None:
    world.services.install(world.unit(argv=(str(world.root / "no-such-program"),)))
    world.refuses(NAME)
    with pytest.raises(ServiceError, match=NAME):
        world.services.start(NAME)
    assert not world.services.state(NAME).running


def test_a_program_that_exits_at_once_is_never_active_and_its_restarts_count(
    world: World,
) -> None:
    world.services.install(world.unit(argv=CRASHER, start_limit=1))
    world.crashes(NAME)
    world.services.start(NAME)  # accepted, as `systemctl start` accepts a simple service
    seen: list[UnitState] = []

    def retried() -> bool:
        seen.append(world.services.state(NAME))
        return seen[-1].restarts >= 1 and seen[-1].active != "active"

    assert wait_for(retried), seen[-1]
    assert not any(s.running for s in seen), seen
    if not world.real:  # supervisord may take a fast exit for a run past startsecs and retry
        assert seen[-1].active == "failed"
    assert wait_for(lambda: world.services.state(NAME).active in ("failed", "activating"))


def test_logs_are_the_last_lines_the_program_printed(world: World) -> None:
    world.services.install(world.unit(argv=PRINTER))
    world.prints(NAME, ["line 1", "line 2", "line 3"])
    world.services.start(NAME)
    assert wait_for(lambda: len(world.services.logs(NAME, 5)) == 3)
    assert world.services.logs(NAME, 2) == ["line 2", "line 3"]
    assert world.services.logs(NAME, 5) == ["line 1", "line 2", "line 3"]


@pytest.mark.parametrize("where", ["argv", "environment"])
def test_a_line_break_is_refused_at_install(world: World, where: str) -> None:
    unit = world.unit(argv=(*SLEEPER, "two\nlines")) if where == "argv" else \
        world.unit(environment={"NOTE": "two\nlines"})
    with pytest.raises(ServiceError, match="line break"):
        world.services.install(unit)
    assert world.services.state(NAME) == UnitState(NAME, known=False)


@pytest.mark.parametrize("where", ["argv", "environment"])
def test_check_refuses_what_install_would_and_changes_nothing(world: World, where: str) -> None:
    world.services.check(world.unit())  # a good unit passes
    unit = world.unit(argv=(*SLEEPER, "two\nlines")) if where == "argv" else \
        world.unit(environment={"NOTE": "two\nlines"})
    with pytest.raises(ServiceError, match="line break"):
        world.services.check(unit)
    assert world.services.state(NAME) == UnitState(NAME, known=False)
    if world.real:  # a check is answered without starting the manager
        assert supervisords(Layout(world.root)) == []


# -- what only a real process manager can show -------------------------------------------


def test_stop_reaches_every_process_of_the_group(sv: World) -> None:
    child_file = sv.root / "app" / "child.pid"
    sv.services.install(sv.unit(argv=("/bin/sh", "-c", "sleep 300 & echo $! > child.pid; wait")))
    sv.services.start(NAME)
    assert wait_for(lambda: child_file.is_file() and child_file.read_text().strip() != "")
    child = int(child_file.read_text())
    try:
        assert alive(child)
        sv.services.stop(NAME)
        assert wait_for(lambda: not alive(child), 3), "the program's child outlived its stop"
    finally:
        kill(child)


def test_a_program_killed_while_running_is_restarted_and_counted(sv: World) -> None:
    sv.services.install(sv.unit())
    sv.services.start(NAME)
    first = sv.services.state(NAME)
    assert first.pid is not None and first.restarts == 0
    os.kill(first.pid, signal.SIGKILL)
    assert wait_for(lambda: sv.services.state(NAME).running
                    and sv.services.state(NAME).pid != first.pid)
    assert sv.services.state(NAME).restarts == 1
    sv.services.restart(NAME)  # a start lpam asks for counts afresh
    assert sv.services.state(NAME).restarts == 0


def test_arguments_arrive_exactly(sv: World) -> None:
    sv.services.install(sv.unit(argv=(PY, "-c", ARGV_DUMP, *AWKWARD)))
    sv.services.start(NAME)
    out = sv.root / "app" / "argv.json"
    assert wait_for(out.is_file)
    assert wait_for(lambda: out.read_text() != "")
    assert json.loads(out.read_text()) == AWKWARD


def test_environment_values_arrive_exactly(sv: World) -> None:
    env = {
        "QUOTED": 'say "hi" now', "COMMAS": "a,b,c", "PERCENT": "100%", "EXPANDED": "%(ENV_X)s",
        "APOSTROPHE": "it's", "EMPTY": "", "EQUALS": "a=b", "DOLLAR": "$HOME",
        "BACKSLASH": "back\\slash", "SEMICOLON": "a;b", "SPACES": " two  spaces ",
        "UNICODE": "café", "MIXED": "a'b\"c",
    }
    sv.services.install(sv.unit(argv=(PY, "-c", ENV_DUMP, *env), environment=env))
    sv.services.start(NAME)
    out = sv.root / "app" / "env.json"
    assert wait_for(lambda: out.is_file() and out.read_text() != "")
    assert json.loads(out.read_text()) == env


@pytest.mark.parametrize("value", ["%(here)s", "a ;b", "x\t#y", "'both\" quotes'"])
def test_an_environment_value_supervisord_would_change_is_refused(
    sv: World, value: str,
) -> None:
    with pytest.raises(ServiceError, match="VALUE"):
        sv.services.install(sv.unit(environment={"VALUE": value}))
    assert not sv.services.state(NAME).known


def test_a_changed_definition_applies_when_stopped_and_waits_for_a_restart_when_running(
    sv: World,
) -> None:
    out = sv.root / "app" / "env.json"

    def run_with(version: str) -> None:
        sv.services.install(sv.unit(argv=(PY, "-c", ENV_DUMP, "VERSION"),
                                    environment={"VERSION": version}))

    def seen() -> str | None:
        assert wait_for(lambda: out.is_file() and out.read_text() != "")
        value = json.loads(out.read_text())["VERSION"]
        out.unlink()
        return str(value)

    run_with("1")
    sv.services.start(NAME)
    assert seen() == "1"
    sv.services.stop(NAME)
    run_with("2")
    sv.services.start(NAME)
    assert seen() == "2"
    pid = sv.services.state(NAME).pid
    run_with("3")  # while it runs: it goes on running version 2
    assert sv.services.state(NAME).pid == pid and sv.services.state(NAME).running
    sv.services.restart(NAME)
    assert seen() == "3"


def test_a_second_instance_for_the_same_root_reuses_the_running_supervisord(sv: World) -> None:
    sv.services.install(sv.unit())
    sv.services.start(NAME)
    [daemon] = supervisords(Layout(sv.root))
    other = SupervisorServices(Layout(sv.root))
    assert other.state(NAME).running
    other.install(sv.unit(name="lpam-app-beta"))
    other.start("lpam-app-beta")
    assert supervisords(Layout(sv.root)) == [daemon]
    assert sv.services.state("lpam-app-beta").running


def test_concurrent_first_use_starts_one_supervisord(sv: World) -> None:
    """Threads stand for lpam processes: flock excludes across open files alike."""
    layout = Layout(sv.root)
    barrier = threading.Barrier(4)
    errors: list[BaseException] = []

    def first_use(i: int) -> None:
        try:
            barrier.wait()
            SupervisorServices(layout).install(sv.unit(name=f"lpam-app-{i}"))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=first_use, args=(i,)) for i in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert errors == []
    assert len(supervisords(layout)) == 1
    assert all(sv.services.state(f"lpam-app-{i}").known for i in range(4))


def test_questions_never_start_supervisord(sv: World) -> None:
    layout = Layout(sv.root)
    assert sv.services.state(NAME) == UnitState(NAME, known=False)
    sv.services.stop(NAME)
    sv.services.uninstall(NAME)
    assert sv.services.logs(NAME) == []
    assert supervisords(layout) == [] and not layout.supervisor_socket.exists()


def test_after_supervisord_is_gone_an_installed_unit_is_known_and_stopped(sv: World) -> None:
    layout = Layout(sv.root)
    sv.services.install(sv.unit())
    assert shutdown(layout) is True
    assert sv.services.state(NAME) == UnitState(NAME, known=True, active="inactive",
                                                sub="stopped")
    assert supervisords(layout) == []
    sv.services.start(NAME)  # as after a reboot: supervisord comes back, the unit runs
    assert sv.services.state(NAME).running


def test_a_dead_supervisord_is_started_anew(sv: World) -> None:
    layout = Layout(sv.root)
    sv.services.install(sv.unit())
    sv.services.start(NAME)
    app = sv.services.state(NAME).pid
    assert app is not None
    [daemon] = supervisords(layout)
    try:
        os.kill(daemon, signal.SIGKILL)
        assert wait_for(lambda: not alive(daemon))
        kill(app)  # orphaned by the kill, and gone; a stale socket and pid file stay behind
        assert wait_for(lambda: not alive(app))
        assert layout.supervisor_socket.exists() and layout.supervisor_pid.exists()
        assert sv.services.state(NAME).active == "inactive"
        sv.services.start(NAME)
        [again] = supervisords(layout)
        assert again != daemon and sv.services.state(NAME).running
    finally:
        kill(app)


def marked(layout: Layout) -> list[int]:
    """Live processes carrying this root's supervisord marks (orphans.py)."""
    from reconciler.adapters.services import orphans

    return orphans.find(Path(os.path.abspath(layout.supervisor_conf)))


def test_what_a_killed_supervisord_ran_is_seen_running_unsupervised(sv: World) -> None:
    layout = Layout(sv.root)
    sv.services.install(sv.unit())
    sv.services.start(NAME)
    app = sv.services.state(NAME).pid
    assert app is not None and marked(layout) == [app]
    [daemon] = supervisords(layout)
    try:
        os.kill(daemon, signal.SIGKILL)
        assert wait_for(lambda: not alive(daemon))
        state = sv.services.state(NAME)
        assert (state.running, state.supervised, state.pid) == (True, False, app)
        assert "its service manager died" in state.describe()
    finally:
        kill(app)


@pytest.mark.parametrize("how", ["start", "restart"])
def test_a_start_after_supervisord_was_killed_never_makes_a_second_copy(
    sv: World, how: str
) -> None:
    """No stop comes first (the record said the start was under way): start itself ends
    what the dead supervisord left running, and a new supervisord runs the one copy."""
    layout = Layout(sv.root)
    sv.services.install(sv.unit())
    sv.services.start(NAME)
    orphan = sv.services.state(NAME).pid
    assert orphan is not None
    [daemon] = supervisords(layout)
    try:
        os.kill(daemon, signal.SIGKILL)
        assert wait_for(lambda: not alive(daemon))
        getattr(sv.services, how)(NAME)
        state = sv.services.state(NAME)
        assert state.running and state.supervised and state.pid != orphan
        assert not alive(orphan) and marked(layout) == [state.pid]
    finally:
        kill(orphan)


def test_a_new_supervisord_starts_only_once_the_old_ones_programs_are_gone(
    sv: World
) -> None:
    """Another unit's start launches the new supervisord: the first unit's orphan is
    ended before it, so nothing of the dead one's runs beside what the new one runs."""
    layout = Layout(sv.root)
    sv.services.install(sv.unit())
    sv.services.start(NAME)
    orphan = sv.services.state(NAME).pid
    assert orphan is not None
    [daemon] = supervisords(layout)
    try:
        os.kill(daemon, signal.SIGKILL)
        assert wait_for(lambda: not alive(daemon))
        sv.services.install(sv.unit("lpam-app-beta"))
        assert not alive(orphan)
        assert sv.services.state(NAME).active == "inactive"
    finally:
        kill(orphan)


def test_shutdown_stops_supervisord_and_its_programs(sv: World) -> None:
    layout = Layout(sv.root)
    sv.services.install(sv.unit())
    sv.services.start(NAME)
    app = sv.services.state(NAME).pid
    [daemon] = supervisords(layout)
    assert app is not None
    assert shutdown(layout) is True
    assert not alive(daemon) and not alive(app)
    assert shutdown(layout) is False


def test_a_socket_path_too_long_is_a_clear_error(tmp_path: Path) -> None:
    layout = Layout(tmp_path / ("deep" * 20))
    services = SupervisorServices(layout)
    try:
        with pytest.raises(ServiceError, match="socket"):
            services.install(Unit(name=NAME, argv=SLEEPER, directory=tmp_path))
        assert supervisords(layout) == []
    finally:
        reap(layout)


def test_a_user_is_refused_when_it_does_not_exist_or_supervisord_cannot_switch(
    sv: World,
) -> None:
    with pytest.raises(ServiceError, match="does not exist"):
        sv.services.install(sv.unit(user="lpam-no-such-user"))
    assert supervisords(Layout(sv.root)) == []
    with pytest.raises(ServiceError, match="only root"):
        check_user(NAME, "root", manager_uid=12345)
    check_user(NAME, "root", manager_uid=0)


# -- the configuration format, against supervisor's own parser (no daemon) ---------------

_PIECES = [*" \t;#%()'\"=,\\$ab_\x0b\x85\u2028é\xa0", "%(here)s", "%(", "s)"]
_TEXT = st.lists(st.sampled_from(_PIECES), max_size=8).map("".join)


def _parsed(folder: Path, unit: Unit) -> tuple[list[str], dict[str, str]]:
    import shlex

    (folder / "programs").mkdir(exist_ok=True)
    (folder / "supervisord.conf").write_text(supervisor_conf.supervisord(
        root=folder, socket=folder / "s.sock", pidfile=folder / "s.pid",
        logfile=folder / "s.log", childlogdir=folder, directory=folder))
    (folder / "programs" / f"{unit.name}.conf").write_text(
        supervisor_conf.program(unit, name=unit.name, log=folder / "out.log"))
    options = ServerOptions()
    options.configfile = str(folder / "supervisord.conf")
    options.process_config(do_usage=False)
    [group] = options.process_group_configs
    [process] = group.process_configs
    return shlex.split(process.command), dict(process.environment)


@settings(max_examples=300, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
@given(args=st.lists(_TEXT, max_size=4),
       env=st.dictionaries(st.sampled_from(["A", "B_2", "c"]), _TEXT, max_size=3))
def test_supervisord_reads_back_exactly_what_was_written_or_it_is_refused(
    tmp_path_factory: pytest.TempPathFactory, args: list[str], env: dict[str, str],
) -> None:
    folder = tmp_path_factory.mktemp("conf")
    unit = Unit(name=NAME, argv=("/bin/true", *args), directory=folder, environment=env)
    try:
        argv, environment = _parsed(folder, unit)
    except ServiceError:
        return
    assert argv == list(unit.argv)
    assert environment == env
