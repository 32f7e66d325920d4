"""The lifecycle steps against the service port (the in-memory twin), one at a time.

A script's exit code is not trusted: what the service manager says about the app's unit
decides whether it runs (started) or may still hold the bus (stopped). A scriptless app's
unit is written and driven by lpam. Health failures are HealthErrors (exit 3). Every
script and unit runs in `/etc/libpanda.d/apps/<folder>`, the link to its generation.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import pytest

from reconciler.adapters.folders import DiskFolders
from reconciler.adapters.memory import MemoryScripts, MemoryStore
from reconciler.adapters.services.memory import MemoryServices
from reconciler.base.errors import HealthError, StepError
from reconciler.base.layout import Layout
from reconciler.core.planning.model import generation_id
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps import RUNNERS
from reconciler.engine.records.state import read_record
from schemas.plan import Phase, StepKind
from schemas.record import StateRecord
from tests.records import sole
from tests.steps_v1 import ArgValue, step

URL, KEY, COMMIT = "git://h/apps", "lab/apps", "a" * 40
TREE = "1" * 40
SCRIPTS = {s: "" for s in ("install.sh", "uninstall.sh", "start.sh", "stop.sh")}
NOW = datetime(2026, 11, 23, tzinfo=timezone.utc)


class Clock:
    """Time that passes only when lpam sleeps: bounded waits end at once, deterministically."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += max(seconds, 0.01)


def machine(tmp_path: Path, services: MemoryServices, files: dict[str, str] | None = None
            ) -> tuple[Context, MemoryScripts]:
    layout = Layout(tmp_path / "root")
    store = MemoryStore(layout=layout, remotes={URL: {COMMIT: {"x": (TREE, files or SCRIPTS)}}})
    store.fetch(KEY, URL)
    scripts = MemoryScripts(runs_dir=layout.runs)
    clock = Clock()
    return Context(layout=layout, store=store, scripts=scripts, services=services,
                   record=StateRecord(lineage="L"), clock=lambda: NOW,
                   monotonic=clock.monotonic, sleep=clock.sleep,
                   folders=DiskFolders(layout=layout, store=store)), scripts


def args(*, service: str | None = None, command: list[str] | None = None,
         settle: str = "2") -> dict[str, ArgValue]:
    how = {"command": '["' + '", "'.join(command) + '"]'} if command else {}
    return {"app": "x", "generation": generation_id(TREE, how), "repository": KEY,
            "commit": COMMIT, "path": "x", "tree": TREE, "params": {"RATE": "5"},
            "service": service, "command": command, "launch": None, "user": None,
            "health": {"settle_seconds": settle, "timeout_seconds": "3"}}


def run(kind: StepKind, ctx: Context, values: dict[str, ArgValue]) -> None:
    phase = Phase.PREPARE if kind is StepKind.STAGE else Phase.CUTOVER
    RUNNERS[kind](step(kind, phase, "x", **values), ctx)


def install(ctx: Context, values: dict[str, ArgValue]) -> None:
    run(StepKind.STAGE, ctx, values)
    run(StepKind.INSTALL, ctx, values)


def test_start_sh_exiting_0_is_not_running_when_its_unit_is_not_active(tmp_path: Path) -> None:
    services = MemoryServices(known_units={"can"})  # start.sh "starts" it, but it never runs
    ctx, scripts = machine(tmp_path, services)
    install(ctx, args(service="can"))
    with pytest.raises(HealthError, match=r"start\.sh exited 0 but unit can is inactive"):
        run(StepKind.START, ctx, args(service="can"))
    app = sole(read_record(ctx.layout))
    assert app is not None and app.status == "starting"  # may be active: stopped on rollback
    assert scripts.calls == ["x:install.sh", "x:start.sh"]


def test_start_sh_counts_once_its_unit_is_active(tmp_path: Path) -> None:
    services = MemoryServices(known_units={"can"})
    ctx, scripts = machine(tmp_path, services)
    install(ctx, args(service="can"))
    real = scripts.run

    def start_the_unit(app: str, app_dir: Path, script: str, *a: object, **k: object) -> bool:
        done = real(app, app_dir, script, *a, **k)  # type: ignore[arg-type]
        if script == "start.sh":
            services.start("can")  # what the app's `systemctl start can` does
        return done

    scripts.run = start_the_unit  # type: ignore[method-assign]
    run(StepKind.START, ctx, args(service="can"))
    app = sole(read_record(ctx.layout))
    assert app is not None and app.status == "running"


def test_a_unit_this_manager_cannot_know_leaves_the_scripts_word(tmp_path: Path) -> None:
    ctx, _ = machine(tmp_path, MemoryServices())  # `can` is a systemd unit; this is not systemd
    install(ctx, args(service="can"))
    run(StepKind.START, ctx, args(service="can"))
    run(StepKind.VERIFY, ctx, args(service="can"))
    app = sole(read_record(ctx.layout))
    assert app is not None and app.status == "running"


def test_stop_sh_exiting_0_while_its_unit_still_runs_stops_the_cutover(tmp_path: Path) -> None:
    services = MemoryServices(known_units={"can"})
    ctx, _ = machine(tmp_path, services)
    install(ctx, args(service="can"))
    services.start("can")
    run(StepKind.START, ctx, args(service="can"))
    with pytest.raises(StepError, match="unit can is still active") as info:
        run(StepKind.STOP, ctx, args(service="can"))
    assert not isinstance(info.value, HealthError)
    app = sole(read_record(ctx.layout))
    assert app is not None and app.status == "stopping"  # never claimed stopped


def test_a_scriptless_app_is_a_unit_lpam_writes_and_drives(tmp_path: Path) -> None:
    services = MemoryServices()
    ctx, scripts = machine(tmp_path, services, {"tick.py": "print('tick')\n"})
    values = args(command=["python3", "tick.py", "--fast"])
    install(ctx, values)
    unit = services.units["lpam-app-x"]
    place = ctx.layout.app_link("x")
    assert place.is_symlink() and place.resolve() == ctx.layout.generation_dir(
        "x", str(values["generation"]))
    assert unit.argv == ("python3", "tick.py", "--fast") or unit.argv[1:] == ("tick.py",
                                                                               "--fast")
    assert unit.directory == place and unit.environment["RATE"] == "5"
    run(StepKind.START, ctx, values)
    run(StepKind.VERIFY, ctx, values)
    assert services.state("lpam-app-x").running
    run(StepKind.STOP, ctx, values)
    run(StepKind.UNINSTALL, ctx, values)
    assert "lpam-app-x" not in services.units and not place.exists()
    assert scripts.calls == []  # no script ran: it has none
    assert not read_record(ctx.layout).apps


def test_a_program_in_the_app_folder_is_run_from_there(tmp_path: Path) -> None:
    services = MemoryServices()
    ctx, _ = machine(tmp_path, services, {"tick": "#!/bin/sh\n"})
    install(ctx, args(command=["tick", "-v"]))
    assert services.units["lpam-app-x"].argv == (str(ctx.layout.app_link("x") / "tick"), "-v")


def test_a_unit_that_crashes_after_start_fails_its_health_check(tmp_path: Path) -> None:
    services = MemoryServices(crash_on_start={"lpam-app-x"})
    ctx, _ = machine(tmp_path, services, {"tick.py": ""})
    values = args(command=["python3", "tick.py"])
    install(ctx, values)
    with pytest.raises(HealthError, match="is failed"):
        run(StepKind.START, ctx, values)


def test_a_unit_that_restarts_while_it_settles_fails_its_health_check(tmp_path: Path) -> None:
    services = MemoryServices()
    ctx, _ = machine(tmp_path, services, {"tick.py": ""})
    values = args(command=["python3", "tick.py"])
    install(ctx, values)
    run(StepKind.START, ctx, values)
    real = services.state
    looks = []

    def flapping(name: str):  # type: ignore[no-untyped-def]
        looks.append(name)
        if len(looks) == 3:
            services.restart(name)  # it died and its manager brought it back
        return real(name)

    services.state = flapping  # type: ignore[method-assign]
    with pytest.raises(HealthError, match="restarted"):
        run(StepKind.VERIFY, ctx, values)


def test_settle_zero_and_a_passing_health_command(tmp_path: Path) -> None:
    services = MemoryServices()
    ctx, scripts = machine(tmp_path, services, {"tick.py": ""})
    values: dict[str, ArgValue] = {**args(command=["python3", "tick.py"], settle="0"),
                                   "health_command": ["./healthy.sh"]}
    install(ctx, values)
    run(StepKind.START, ctx, values)
    run(StepKind.VERIFY, ctx, values)
    assert scripts.calls == ["x:check"]
    scripts.fail.add("x:check")
    with pytest.raises(HealthError, match=r"health check `\./healthy\.sh` failed"):
        run(StepKind.VERIFY, ctx, values)


def test_a_change_of_params_rewrites_the_unit_without_install(tmp_path: Path) -> None:
    services = MemoryServices()
    ctx, _ = machine(tmp_path, services, {"tick.py": ""})
    values = args(command=["python3", "tick.py"])
    install(ctx, values)
    run(StepKind.CONFIGURE, ctx, {**values, "params": {"RATE": "9"}})
    assert services.units["lpam-app-x"].environment["RATE"] == "9"
    app = sole(read_record(ctx.layout))
    assert app is not None and app.params == {"RATE": "9"}
    assert [c for c in services.calls if c[0] == "install"] == [
        ("install", "lpam-app-x"), ("install", "lpam-app-x")]


def test_an_lpam_app_whose_unit_outlives_its_stop_sh_blocks_the_cutover(tmp_path: Path) -> None:
    """Taking over LPAM's app: its own stop.sh runs, and its unit must then be inactive."""
    from schemas.record import Stray

    services = MemoryServices(known_units={"pandarecord"})
    services.start("pandarecord")  # LPAM left it running
    ctx, scripts = machine(tmp_path, services)
    folder = ctx.layout.libpanda_apps / "pandarecord"
    folder.mkdir(parents=True)
    (folder / "stop.sh").write_text("true\n")  # exits 0, stops nothing
    (folder / "service").write_text("pandarecord\n")
    stray = Stray(name="pandarecord", generation="lpam", folder="pandarecord")
    ctx.save(ctx.record.model_copy(update={"strays": [stray]}))
    taken: dict[str, ArgValue] = {"app": "pandarecord", "generation": "lpam", "params": {},
                                  "stray": "yes"}
    with pytest.raises(StepError, match="unit pandarecord is still active"):
        run(StepKind.STOP, ctx, taken)
    [left] = read_record(ctx.layout).strays
    assert not left.stopped and left.run is None  # not settled as stopped: stopped again
    services.stop("pandarecord")
    run(StepKind.STOP, ctx, taken)
    assert read_record(ctx.layout).strays[0].stopped
    assert scripts.calls == ["pandarecord:stop.sh", "pandarecord:stop.sh"]


def test_a_unit_that_cannot_be_written_is_refused_while_preparing(tmp_path: Path) -> None:
    """Checked at staging, while the old app still runs — not after it was stopped."""
    services = MemoryServices()
    ctx, _ = machine(tmp_path, services, {"tick.py": ""})
    values: dict[str, ArgValue] = {**args(command=["python3", "tick.py"]),
                                   "params": {"NOTE": "two\nlines"}}
    with pytest.raises(StepError, match="x: unit lpam-app-x: the value of NOTE holds a line"):
        run(StepKind.STAGE, ctx, values)
    assert services.units == {} and services.calls == [("check", "lpam-app-x")]


@pytest.mark.parametrize("underlay", [None, "/opt/ros/noetic/setup.bash"])
def test_a_launch_app_without_a_build_of_its_own_runs_in_the_ros_distribution(
    tmp_path: Path, underlay: str | None
) -> None:
    """On the Pi roslaunch is on PATH only once /opt/ros/noetic/setup.bash is sourced;
    Debian's own roslaunch (this machine's) needs nothing."""
    from reconciler.engine.execution import supervision

    services = MemoryServices()
    ctx, _ = machine(tmp_path, services, {"description.txt": "vsl\n"})
    ctx.underlay = lambda: None if underlay is None else Path(underlay)
    values = {**args(), "launch": "can_to_ros/vsl.launch",
              "generation": generation_id(TREE, {"launch": "can_to_ros/vsl.launch"})}
    install(ctx, values)
    argv = services.units["lpam-app-x"].argv
    if underlay is None:
        assert argv == ("roslaunch", "can_to_ros", "vsl.launch")
    else:
        assert argv == ("bash", "-c", supervision.ROS_WRAPPER, "lpam-ros", underlay,
                        "roslaunch", "can_to_ros", "vsl.launch")
