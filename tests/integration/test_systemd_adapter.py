"""The systemd adapter at its boundary: real files under a temporary root, a recording fake
`systemctl` and `journalctl` first on PATH (no systemd manager is ever asked anything),
and every unit it writes checked by `systemd-analyze verify`.

The fake appends its argv as one JSON line to `calls.jsonl`, answers `show` with the
lines of `show.txt` whose keys were asked for (as systemctl does), prints `journal.txt`
for journalctl, and fails as `fail-<tool>-<verb>.json` says ({"code", "stderr", "sleep"}).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from reconciler.adapters.services.choice import choose
from reconciler.adapters.services.systemd import SystemdServices
from reconciler.adapters.services.unitfile import HEADER
from reconciler.base.errors import LpamError, ServiceError
from reconciler.base.layout import Layout
from reconciler.base.unit import Unit, UnitState

FIXTURES = Path(__file__).parent.parent / "fixtures" / "systemctl"
NAME = "lpam-app-demo"
UNIT = f"{NAME}.service"

FAKE = """#!{python}
import json, os, sys, time
state = os.environ["LPAM_FAKE_SYSTEMD"]
tool = os.path.basename(sys.argv[0])
args = sys.argv[1:]
with open(os.path.join(state, "calls.jsonl"), "a") as log:
    log.write(json.dumps([tool, *args]) + "\\n")
verb = "journal" if tool == "journalctl" else next((a for a in args if a[:1] != "-"), "")
fail = os.path.join(state, "fail-%s-%s.json" % (tool, verb))
if os.path.exists(fail):
    with open(fail) as f:
        spec = json.load(f)
    time.sleep(spec.get("sleep", 0))
    sys.stderr.write(spec.get("stderr", ""))
    sys.exit(spec.get("code", 1))
if verb == "show":
    wanted = {{p for a in args if a.startswith("--property=") for p in a[11:].split(",")}}
    with open(os.path.join(state, "show.txt")) as f:
        for line in f.read().splitlines():
            if line.split("=", 1)[0] in wanted:
                print(line)
elif verb == "journal":
    with open(os.path.join(state, "journal.txt")) as f:
        sys.stdout.write(f.read())
"""


@dataclass
class Fake:
    state: Path
    bin: Path

    def calls(self) -> list[list[str]]:
        log = self.state / "calls.jsonl"
        lines = log.read_text().splitlines() if log.exists() else []
        log.unlink(missing_ok=True)
        return [json.loads(line) for line in lines]

    def show(self, text: str) -> None:
        (self.state / "show.txt").write_text(text)

    def fail(self, tool: str, verb: str, *, stderr: str = "", code: int = 1,
             sleep: float = 0.0) -> None:
        (self.state / f"fail-{tool}-{verb}.json").write_text(
            json.dumps({"stderr": stderr, "code": code, "sleep": sleep}))


@pytest.fixture
def fake(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Fake]:
    state, bindir = tmp_path / "fake-state", tmp_path / "fake-bin"
    state.mkdir()
    bindir.mkdir()
    for tool in ("systemctl", "journalctl"):
        script = bindir / tool
        script.write_text(FAKE.format(python=sys.executable))
        script.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}")
    monkeypatch.setenv("LPAM_FAKE_SYSTEMD", str(state))
    # The one guarantee this whole file rests on: the real systemctl is never run.
    assert shutil.which("systemctl") == str(bindir / "systemctl")
    assert shutil.which("journalctl") == str(bindir / "journalctl")
    fake = Fake(state=state, bin=bindir)
    fake.show("LoadState=not-found\nActiveState=inactive\nSubState=dead\n")
    (state / "journal.txt").write_text("")
    yield fake


@pytest.fixture
def layout(tmp_path: Path) -> Layout:
    return Layout(root=tmp_path / "root")


@pytest.fixture
def app_dir(tmp_path: Path) -> Path:
    folder = tmp_path / "app folder"
    folder.mkdir()
    return folder


def demo(app_dir: Path, **changes: object) -> Unit:
    fields: dict[str, object] = {
        "name": NAME, "argv": ("/bin/sh", "-c", 'echo "100% $HOME" \\ done'),
        "directory": app_dir, "environment": {"SPEED": "5 m/s", "PCT": "50%"},
        "user": "root", "description": "lpam app demo (0123456789ab-cdef0123)",
    }
    fields.update(changes)
    return Unit(**fields)  # type: ignore[arg-type]


def verify(path: Path) -> str:
    tool = shutil.which("systemd-analyze", path="/usr/bin:/bin:/usr/sbin:/sbin")
    if tool is None:
        pytest.skip("systemd-analyze is not installed")
    proc = subprocess.run([tool, "verify", str(path)], capture_output=True, text=True,
                          timeout=60, check=False, cwd=path.parent,
                          env={"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8",
                               "HOME": str(path.parent)})
    return proc.stderr


def loaded(*, need_reload: str = "no", active: str = "active", path: Path | None = None) -> str:
    text = (f"MainPID=0\nNRestarts=0\nLoadState=loaded\nActiveState={active}\nSubState=x\n"
            f"NeedDaemonReload={need_reload}\n")
    return text + (f"FragmentPath={path}\n" if path else "")


# -- install ------------------------------------------------------------------------------

def test_install_writes_a_verified_unit_reloads_and_enables(
    fake: Fake, layout: Layout, app_dir: Path,
) -> None:
    services = SystemdServices(layout)
    services.install(demo(app_dir))
    path = layout.root / "etc" / "systemd" / "system" / UNIT
    assert path == services.unit_file(NAME) == layout.systemd_units / UNIT
    text = path.read_text()
    assert text.startswith(HEADER)
    assert f"WorkingDirectory={app_dir}\n" in text
    assert 'Environment="PCT=50%%"\n' in text
    assert oct(path.stat().st_mode & 0o777) == "0o644"
    assert verify(path) == ""
    assert fake.calls() == [
        ["systemctl", "daemon-reload"],
        ["systemctl", "--no-reload", "enable", "--", UNIT],
    ]


def test_install_reloads_only_when_the_unit_changed_or_systemd_holds_a_stale_copy(
    fake: Fake, layout: Layout, app_dir: Path,
) -> None:
    services = SystemdServices(layout)
    services.install(demo(app_dir))
    fake.calls()
    fake.show(loaded(need_reload="no"))
    services.install(demo(app_dir))
    show = ["systemctl", "show", "--property=LoadState,NeedDaemonReload", "--", UNIT]
    enable = ["systemctl", "--no-reload", "enable", "--", UNIT]
    assert fake.calls() == [show, enable]

    fake.show(loaded(need_reload="yes"))  # a reload cut short by a crash after the write
    services.install(demo(app_dir))
    assert fake.calls() == [show, ["systemctl", "daemon-reload"], enable]

    fake.show(loaded(need_reload="no"))
    services.install(demo(app_dir, environment={"SPEED": "6 m/s"}))
    assert fake.calls() == [["systemctl", "daemon-reload"], enable]
    assert '"SPEED=6 m/s"' in services.unit_file(NAME).read_text()


def test_install_resolves_a_bare_program_on_the_apps_path(
    fake: Fake, layout: Layout, app_dir: Path, tmp_path: Path,
) -> None:
    tools = tmp_path / "ros bin"
    tools.mkdir()
    (tools / "roslaunch").write_text("#!/bin/sh\n")
    (tools / "roslaunch").chmod(0o755)
    services = SystemdServices(layout)
    services.install(demo(app_dir, argv=("roslaunch", "pkg", "x.launch"),
                          environment={"PATH": f"{tools}:/usr/bin"}))
    assert f'ExecStart="{tools}/roslaunch" "pkg" "x.launch"\n' in \
        services.unit_file(NAME).read_text()
    assert verify(services.unit_file(NAME)) == ""
    with pytest.raises(ServiceError, match="'no-such-program' is not on PATH"):
        services.install(demo(app_dir, argv=("no-such-program",),
                              environment={"PATH": str(tools)}))


def test_install_refuses_what_systemd_cannot_hold_and_writes_nothing(
    fake: Fake, layout: Layout, app_dir: Path,
) -> None:
    services = SystemdServices(layout)
    with pytest.raises(ServiceError, match=f"cannot write the systemd unit {UNIT}: .*line break"):
        services.install(demo(app_dir, environment={"A": "two\nlines"}))
    assert not services.unit_file(NAME).exists()
    assert fake.calls() == []


def test_install_and_uninstall_leave_a_unit_lpam_did_not_write_alone(
    fake: Fake, layout: Layout, app_dir: Path,
) -> None:
    services = SystemdServices(layout)
    path = services.unit_file(NAME)
    path.parent.mkdir(parents=True)
    path.write_text("[Service]\nExecStart=/bin/true\n")
    with pytest.raises(ServiceError, match="not written by lpam"):
        services.install(demo(app_dir))
    with pytest.raises(ServiceError, match="not written by lpam"):
        services.uninstall(NAME)
    assert path.read_text() == "[Service]\nExecStart=/bin/true\n"
    assert fake.calls() == []


# -- uninstall ----------------------------------------------------------------------------

def test_uninstall_stops_disables_removes_and_reloads_then_is_a_no_op(
    fake: Fake, layout: Layout, app_dir: Path,
) -> None:
    services = SystemdServices(layout)
    services.install(demo(app_dir))
    fake.calls()
    path = services.unit_file(NAME)
    fake.show(loaded(active="active", path=path))
    services.uninstall(NAME)
    assert not path.exists()
    assert fake.calls() == [
        ["systemctl", "show",
         "--property=LoadState,ActiveState,SubState,NRestarts,MainPID,FragmentPath", "--", UNIT],
        ["systemctl", "stop", "--", UNIT],
        ["systemctl", "reset-failed", "--", UNIT],
        ["systemctl", "--no-reload", "disable", "--", UNIT],
        ["systemctl", "daemon-reload"],
    ]
    fake.show("MainPID=0\nNRestarts=0\nLoadState=not-found\nActiveState=inactive\n")
    services.uninstall(NAME)
    services.uninstall(f"{NAME}.service")
    assert [call[1] for call in fake.calls()] == ["show", "show"]


def test_uninstall_finishes_one_cut_short_after_the_file_was_removed(
    fake: Fake, layout: Layout,
) -> None:
    services = SystemdServices(layout)
    fake.show(loaded(active="inactive", need_reload="yes", path=services.unit_file(NAME)))
    services.uninstall(NAME)
    assert [call[1:] for call in fake.calls()][1:] == [
        ["reset-failed", "--", UNIT], ["daemon-reload"]]


def test_uninstall_leaves_a_unit_loaded_from_elsewhere_alone(
    fake: Fake, layout: Layout,
) -> None:
    fake.show(loaded(path=Path("/lib/systemd/system") / UNIT))
    SystemdServices(layout).uninstall(NAME)
    assert [call[1] for call in fake.calls()] == ["show"]


# -- acting and asking --------------------------------------------------------------------

def test_start_stop_restart_are_argument_lists(fake: Fake, layout: Layout) -> None:
    services = SystemdServices(layout)
    services.start(NAME)
    services.stop(f"{NAME}.service")
    services.restart(NAME)
    assert fake.calls() == [["systemctl", verb, "--", UNIT]
                            for verb in ("start", "stop", "restart")]


def test_a_failing_start_names_the_unit_and_quotes_systemctl(
    fake: Fake, layout: Layout,
) -> None:
    fake.fail("systemctl", "start", code=1, stderr=(
        f"Job for {UNIT} failed because the control process exited with error code.\n"
        f'See "systemctl status {UNIT}" and "journalctl -xeu {UNIT}" for details.\n'))
    with pytest.raises(ServiceError) as caught:
        SystemdServices(layout).start(NAME)
    error = caught.value
    assert error.message.startswith(f"`systemctl start -- {UNIT}` failed with exit code 1: "
                                     f"Job for {UNIT} failed because")
    assert "\n" not in error.message
    assert error.hint is not None and f"systemctl status {UNIT}" in error.hint


def test_a_flood_of_stderr_stays_one_short_line(fake: Fake, layout: Layout) -> None:
    fake.fail("systemctl", "restart", stderr="x" * 100_000 + "\n" * 1000)
    with pytest.raises(ServiceError) as caught:
        SystemdServices(layout).restart(NAME)
    assert len(caught.value.message) < 500
    assert "\n" not in caught.value.message


def test_access_denied_hints_at_root(fake: Fake, layout: Layout) -> None:
    fake.fail("systemctl", "start", code=4, stderr=(
        f"Failed to start {UNIT}: Access denied\nSee system logs and 'systemctl status "
        f"{UNIT}' for details.\n"))
    with pytest.raises(ServiceError) as caught:
        SystemdServices(layout).start(NAME)
    assert caught.value.hint is not None and "sudo" in caught.value.hint


def test_stop_of_a_unit_systemd_does_not_know_is_done(fake: Fake, layout: Layout) -> None:
    fake.fail("systemctl", "stop", code=5, stderr=f"Failed to stop {UNIT}: Unit {UNIT} not "
              "loaded.\n")
    services = SystemdServices(layout)
    services.stop(NAME)
    fake.show(loaded(active="active"))
    with pytest.raises(ServiceError, match="exit code 5"):
        services.stop(NAME)


def test_a_call_over_its_time_limit_fails(fake: Fake, layout: Layout) -> None:
    fake.fail("systemctl", "start", sleep=5)
    with pytest.raises(ServiceError, match=r"did not finish within 0\.5 s"):
        SystemdServices(layout, act_timeout=0.5).start(NAME)


@pytest.mark.parametrize("fixture", sorted(p.stem for p in FIXTURES.glob("*.txt")))
def test_state_end_to_end(fake: Fake, layout: Layout, fixture: str) -> None:
    text = (FIXTURES / f"{fixture}.txt").read_text()
    fake.show(text)
    state = SystemdServices(layout).state(NAME)
    assert state.name == NAME
    assert fake.calls() == [["systemctl", "show",
                             "--property=LoadState,ActiveState,SubState,NRestarts,MainPID",
                             "--", UNIT]]
    assert state.known == ("LoadState=not-found" not in text)


def test_state_of_a_running_unit(fake: Fake, layout: Layout) -> None:
    fake.show((FIXTURES / "extra-properties.txt").read_text())
    assert SystemdServices(layout).state(NAME) == UnitState(
        NAME, known=True, active="active", sub="reload", restarts=1, pid=2211)


def test_state_without_a_systemd_to_ask(fake: Fake, layout: Layout) -> None:
    fake.fail("systemctl", "show", stderr="System has not been booted with systemd as init "
              "system (PID 1). Can't operate.\nFailed to connect to bus: Host is down\n")
    with pytest.raises(ServiceError) as caught:
        SystemdServices(layout).state(NAME)
    assert caught.value.hint is not None and "--services supervisor" in caught.value.hint


def test_systemctl_missing_from_path(
    layout: Layout, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    with pytest.raises(ServiceError, match="systemctl is not on PATH") as caught:
        SystemdServices(layout).state(NAME)
    assert caught.value.hint is not None and "supervisor" in caught.value.hint


def test_an_explicit_systemctl_is_used(fake: Fake, layout: Layout, tmp_path: Path) -> None:
    other = tmp_path / "other-systemctl"
    shutil.copy(fake.bin / "systemctl", other)
    SystemdServices(layout, systemctl=str(other)).start(NAME)
    assert fake.calls() == [["other-systemctl", "start", "--", UNIT]]


@pytest.mark.parametrize("name", ["../../etc/passwd", "-x", "--now", "a b", ""])
def test_names_are_checked_before_anything_runs(fake: Fake, layout: Layout, name: str) -> None:
    services = SystemdServices(layout)
    for act in (services.start, services.stop, services.state, services.uninstall):
        with pytest.raises(ServiceError, match="not a service name"):
            act(name)
    assert fake.calls() == []


def test_logs(fake: Fake, layout: Layout) -> None:
    (fake.state / "journal.txt").write_text("first\nsecond é\n")
    assert SystemdServices(layout).logs(NAME, 7) == ["first", "second é"]
    assert fake.calls() == [["journalctl", "-u", UNIT, "-n", "7", "--no-pager", "-o", "cat",
                             "--quiet"]]
    fake.fail("journalctl", "journal", stderr="Failed to open journal: Permission denied\n")
    with pytest.raises(ServiceError, match="Permission denied"):
        SystemdServices(layout).logs(NAME)


# -- choosing the backend -----------------------------------------------------------------

def test_choice_override_then_environment_then_machine(tmp_path: Path) -> None:
    booted = tmp_path / "run" / "systemd" / "system"
    absent = tmp_path / "nothing"
    booted.mkdir(parents=True)
    assert choose(override=None, env={}, booted=booted) == "systemd"
    assert choose(override=None, env={}, booted=absent) == "supervisor"
    assert choose(override=None, env={"LPAM_SERVICES": ""}, booted=absent) == "supervisor"
    assert choose(override=None, env={"LPAM_SERVICES": "systemd"}, booted=absent) == "systemd"
    assert choose(override="supervisor", env={"LPAM_SERVICES": "systemd"},
                  booted=booted) == "supervisor"


@pytest.mark.parametrize(("override", "env", "source"), [
    ("memory", {}, "--services"),
    (None, {"LPAM_SERVICES": "Systemd"}, "LPAM_SERVICES"),
    (None, {"LPAM_SERVICES": "supervisord"}, "LPAM_SERVICES"),
])
def test_choice_refuses_unknown_managers(
    override: str | None, env: dict[str, str], source: str, tmp_path: Path,
) -> None:
    with pytest.raises(LpamError, match=f"{source}=.* names no service manager") as caught:
        choose(override=override, env=env, booted=tmp_path)
    assert caught.value.hint is not None and "systemd or supervisor" in caught.value.hint


def test_check_verifies_the_unit_offline_and_asks_systemctl_nothing(
    fake: Fake, layout: Layout, app_dir: Path, tmp_path: Path
) -> None:
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze is not installed")
    services = SystemdServices(layout)
    services.check(demo(app_dir))
    assert fake.calls() == [] and not services.unit_file(NAME).exists()
    with pytest.raises(ServiceError, match="not on PATH"):
        services.check(demo(app_dir, argv=("no-such-program-here", "x")))
    plain = tmp_path / "not-a-program"
    plain.write_text("data\n")  # exists, but cannot be executed
    with pytest.raises(ServiceError, match="does not verify") as info:
        services.check(demo(app_dir, argv=(str(plain),)))
    assert str(tmp_path / "lpam-verify") not in info.value.message
    assert fake.calls() == []


def test_install_agent_writes_verified_units_then_enables_and_starts_them(
    fake: Fake, tmp_path: Path,
) -> None:
    """`lpam install-agent` on a car: both units pass `systemd-analyze verify` with nothing
    said, and are enabled and started through (the recording) systemctl."""
    root = tmp_path / "root"
    config = root / "etc/lpam/agent.yaml"
    config.parent.mkdir(parents=True)
    config.write_text("version: 1\nsource: {url: 'git://192.168.4.1/fleet.git'}\n"
                      "vehicle: rav4-07\n")
    done = subprocess.run([sys.executable, "-m", "reconciler", "--root", str(root),
                           "install-agent", "--services", "systemd"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    units = root / "etc/systemd/system"
    agent, fetch = units / "lpam-agent.service", units / "lpam-agent-fetch.service"
    assert verify(agent) == "" and verify(fetch) == ""
    assert f'ExecStart="{sys.executable}" "-m" "reconciler" "--root" "{root}" "agent"' in \
        agent.read_text()
    assert '"sync" "--fetch-only"' in fetch.read_text() and "ExecStop=" in fetch.read_text()
    calls = [c for c in fake.calls() if c[0] == "systemctl"]
    for name in ("lpam-agent.service", "lpam-agent-fetch.service"):
        assert ["systemctl", "--no-reload", "enable", "--", name] in calls
        assert ["systemctl", "start", "--", name] in calls


def test_install_ble_writes_a_verified_unit_that_replaces_bluezone(
    fake: Fake, tmp_path: Path,
) -> None:
    """`lpam install-ble`: the unit verifies, runs `lpam ble` on this root after bluetoothd,
    stops bluezone (the same GATT service cannot be served twice), and is enabled and
    started through (the recording) systemctl."""
    root = tmp_path / "root"
    done = subprocess.run([sys.executable, "-m", "reconciler", "--root", str(root),
                           "install-ble", "--services", "systemd"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    unit = root / "etc/systemd/system/lpam-ble.service"
    assert verify(unit) == ""
    text = unit.read_text()
    assert f'ExecStart="{sys.executable}" "-m" "reconciler" "--root" "{root}" "ble"\n' in text
    assert "Conflicts=bluezone.service" in text and "After=bluetooth.service" in text
    calls = [c for c in fake.calls() if c[0] == "systemctl"]
    assert ["systemctl", "--no-reload", "enable", "--", "lpam-ble.service"] in calls
    assert ["systemctl", "start", "--", "lpam-ble.service"] in calls
    # a lab's car: the unit's command keeps bluezone's open writes (issue 31)
    done = subprocess.run([sys.executable, "-m", "reconciler", "--root", str(root),
                           "install-ble", "--services", "systemd", "--writes", "open"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert verify(unit) == ""
    assert f'"--root" "{root}" "ble" "--writes" "open"\n' in unit.read_text()


def test_install_agent_refuses_a_bad_agent_yaml_and_writes_nothing(
    fake: Fake, tmp_path: Path,
) -> None:
    root = tmp_path / "root"
    config = root / "etc/lpam/agent.yaml"
    config.parent.mkdir(parents=True)
    config.write_text("version: 1\nsource: {url: 'git://h/fleet.git'}\nvehicle: 'a b'\n")
    done = subprocess.run([sys.executable, "-m", "reconciler", "--root", str(root),
                           "install-agent", "--services", "systemd"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 1 and "agent.yaml:3:1: vehicle: vehicle id" in done.stderr
    assert not (root / "etc/systemd/system").exists() and fake.calls() == []
