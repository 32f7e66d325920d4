"""Issue 33's drive: which software ran while each recording was made, checked against what
the test knows ran.

Real processes under the root's supervisord, from a real git daemon: a recorder writing
libpanda-style CSVs (a `Time` column) and candump logs, one file pair per drive, while the
desired state switches the controller twice mid-file; an operator stop and start; a crash
the service manager restarts; a power cut (kill -9 of supervisord and every app, then
lpam again from the disk as left, in a new boot); the car's wall clock 5 hours behind at
each boot until "GPS" sets it. lpam runs in-process through the workflow's functions, so
the one thing the test plays is the clock: the Machine's `clock` and `stamp` ports (the
boot id, boottime since that boot, and the car's wall clock). The recorder writes true
time, as data stamped from GPS does.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from reconciler.engine.records.timeline import Timeline
from reconciler.workflow import provenance as prov
from reconciler.workflow.applying import ApplyOptions, apply_file
from reconciler.workflow.machine import Machine
from reconciler.workflow.operate import operate_installed
from schemas.operator import OperatorAction
from schemas.timeline import Sidecar, Stamp
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import processes
from tests.integration.test_fault_truth import BUS

SKEW = -5 * 3600.0  # the Pi's clock at boot: the last shutdown's, hours behind

RECORDER = """\
import os, time
root = os.environ["LPAM_ROOT"]
data = os.path.join(root, "data")
os.makedirs(data, exist_ok=True)
vin = open(os.path.join(root, "etc/libpanda.d/vin")).read().strip()
while True:
    with open(os.path.join(root, "drive")) as f:
        drive = f.read().strip()
    now = time.time()
    csv = os.path.join(data, f"{drive}_{vin}_CAN_Messages.csv")
    new = not os.path.exists(csv)
    if new:  # as pandarecord does: currentCan.csv names the file being written
        link = os.path.join(root, "etc/libpanda.d/currentCan.csv")
        if os.path.lexists(link):
            os.unlink(link)
        os.symlink(csv, link)
    with open(csv, "a") as f:
        if new:
            f.write("Time,Bus,MessageID,Message,MessageLength\\n")
        f.write(f"{now:.6f},0,384,0011223344556677,8\\n")
    with open(os.path.join(data, f"{drive}.log"), "a") as f:
        f.write(f"({now:.6f}) can0 180#0011223344556677\\n")
    time.sleep(0.05)
"""

CATALOG = """\
apps:
  - name: ctl-a
    command: [python3, -u, bus.py]
    health: {settle_seconds: 0.5}
    properties:
      - owns_panda: true
  - name: ctl-b
    command: [python3, -u, bus.py]
    health: {settle_seconds: 0.5}
    properties:
      - owns_panda: true
  - name: recorder
    command: [python3, -u, recorder.py]
    health: {settle_seconds: 0.5}
    data: [/data/*]
"""

VIN = "2T3Y1RFV8KC014025"


def state(url: str, controller: str, gain: str = "1") -> str:
    return (f"version: 2\nrepositories:\n  - url: {url}\napps:\n  - name: {controller}\n"
            f"    params: {{GAIN: \"{gain}\"}}\n  - name: recorder\n")


@dataclass
class Car:
    """The car's clock as the test plays it, and what the test knows ran when (true time)."""

    root: Path
    boot: str = "boot-1"
    base: float = field(default_factory=lambda: _boottime() - 100.0)
    skew: float = SKEW
    # (true time a change began, true time it ended, what ran after it)
    truth: list[tuple[float, float, frozenset[tuple[str, str]]]] = field(default_factory=list)

    def wall(self) -> datetime:
        return datetime.now(timezone.utc) + timedelta(seconds=self.skew)

    def stamp(self) -> Stamp:
        return Stamp(boot=self.boot, mono=round(_boottime() - self.base, 3), wall=self.wall())

    def machine(self) -> Machine:
        machine = Machine.at(Layout(self.root), services="supervisor")
        machine.clock = self.wall
        machine.stamp = self.stamp
        return machine

    @contextlib.contextmanager
    def change(self) -> Iterator[None]:
        """A change of what runs: between its start and its end, either may have run."""
        began = time.time()
        yield
        self.truth.append((began, time.time(), self.running()))

    def running(self) -> frozenset[tuple[str, str]]:
        """What runs now, as the state record says (after an apply, the truth)."""
        record = json.loads((self.root / "var/lib/lpam/state.json").read_text())
        return frozenset((a["name"], a["generation"]) for a in record["apps"]
                         if a["status"] == "running")

    def steady(self) -> Iterator[tuple[float, float, frozenset[tuple[str, str]]]]:
        """(from, to, what ran): the spans between two changes, when nothing changed."""
        for (_, since, apps), (until, _, _) in zip(self.truth, self.truth[1:]):
            yield since, until, apps

    def ran(self, start: float, end: float) -> set[tuple[str, str]]:
        """Everything that may have run at some instant of [start, end]."""
        out: set[tuple[str, str]] = set()
        before: frozenset[tuple[str, str]] = frozenset()
        for i, (began, ended, apps) in enumerate(self.truth):
            until = self.truth[i + 1][0] if i + 1 < len(self.truth) else float("inf")
            if began <= end and ended >= start:  # during the change: before or after
                out |= before | apps
            if ended <= end and until >= start:
                out |= apps
            before = apps
        return out


def _boottime() -> float:
    return time.clock_gettime(getattr(time, "CLOCK_BOOTTIME", time.CLOCK_MONOTONIC))


@pytest.fixture
def car(tmp_path: Path) -> Iterator[Car]:
    root = tmp_path / "root"
    (root / "etc/libpanda.d").mkdir(parents=True)
    (root / "etc/libpanda.d/vin").write_text(VIN + "\n")
    (root / "drive").write_text("drive1\n")
    yield Car(root)
    shutdown(Layout(root))
    for pid in processes(root):
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)


@pytest.fixture
def url(make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon) -> str:
    builder = make_repo("car.git")
    builder.write("libpanda-apps.yaml", CATALOG)
    for app in ("ctl-a", "ctl-b"):
        builder.write(f"{app}/bus.py", BUS)
    builder.write("recorder/recorder.py", RECORDER)
    builder.commit("two controllers and a recorder")
    builder.push()
    return git_daemon.url("car.git")


def apply(car: Car, text: str) -> None:
    path = car.root / "etc/lpam/desired-state.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    with car.change():
        apply_file(car.machine(), path, options=ApplyOptions(), confirm=lambda plan: True,
                   report=lambda event: None)


def operate(car: Car, action: OperatorAction, app: str) -> None:
    with car.change():
        operate_installed(car.machine(), action, file=None, force=True,
                          options=ApplyOptions(), report=lambda event: None, app=app)


def power_cut(car: Car) -> None:
    """kill -9 of supervisord and of every app: nothing runs, nothing was told."""
    began = time.time()
    pidfile = Layout(car.root).supervisor_pid
    with contextlib.suppress(OSError, ValueError):
        os.kill(int(pidfile.read_text().strip()), signal.SIGKILL)
    for pid in processes(car.root):
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 10
    while processes(car.root) and time.monotonic() < deadline:
        time.sleep(0.05)
    car.truth.append((began, time.time(), frozenset()))


def drive(car: Car, name: str) -> None:
    (car.root / "drive.new").write_text(name + "\n")  # whole, never read half-written
    os.replace(car.root / "drive.new", car.root / "drive")
    time.sleep(0.3)  # the recorder's next row goes to the new file


def test_every_file_and_instant_names_what_ran(car: Car, url: str) -> None:
    apply(car, state(url, "ctl-a"))                 # drive1 begins: ctl-a, recorder
    time.sleep(1)
    apply(car, state(url, "ctl-b"))                 # switch 1, mid-file
    time.sleep(1)
    car.skew = 0.0                                  # GPS sets the clock: +5 h
    car.machine().look()
    apply(car, state(url, "ctl-a", gain="2"))       # switch 2, mid-file, new params
    time.sleep(1)
    operate(car, OperatorAction.STOP, "ctl-a")
    time.sleep(1)
    operate(car, OperatorAction.START, "ctl-a")
    car.machine().look()                            # notes the units' pids
    [recorder] = [p for p in processes(car.root, b"recorder.py")]
    os.kill(recorder, signal.SIGKILL)               # a crash supervisord restarts
    deadline = time.monotonic() + 15
    while processes(car.root, b"recorder.py") in ([], [recorder]):
        assert time.monotonic() < deadline, "supervisord did not restart the recorder"
        time.sleep(0.1)
    car.machine().look()
    drive(car, "drive2")                            # drive1 is finished
    time.sleep(1.5)
    power_cut(car)
    time.sleep(1)
    car.boot, car.base, car.skew = "boot-2", _boottime(), SKEW   # the next boot
    drive(car, "drive3")
    apply(car, state(url, "ctl-a", gain="2"))       # lpam starts the apps again
    time.sleep(1)
    car.skew = 0.0
    car.machine().look()
    time.sleep(1)
    drive(car, "drive4")

    known = prov.known(Timeline(Layout(car.root)))
    kinds = [(e.kind, e.how) for e in known.edges]
    assert ("restarted", "crashed") in kinds and ("ended", "power-lost") in kinds
    assert kinds.count(("clock", "clock")) == 2, kinds

    # every instant between two changes, well away from them: exactly what ran
    for since, until, apps in car.steady():
        if until - since < 0.6:
            continue
        middle = datetime.fromtimestamp((since + until) / 2, tz=timezone.utc)
        answer = prov.between(middle, middle, known)
        said = {(i.app, i.generation) for i in answer.found}
        if not apps:  # after the power cut: only what may have run, never said as fact
            assert all(i.ended is not None and i.ended.certainty == "uncertain"
                       for i in answer.found), answer
            continue
        assert said == set(apps), (middle, answer)

    # the first boot's early edges were written 5 h behind and are corrected
    first = known.found[0]
    assert first.began.certainty == "corrected"
    assert car.truth[0][0] - 1 < first.began.when.timestamp() < car.truth[0][1] + 1

    for name in ("drive1", "drive2", "drive3"):
        for path in (car.root / "data").glob(f"{name}[._]*"):
            answer = prov.of_file(path, known)
            assert answer.span is not None and answer.span.source in ("csv", "candump")
            assert answer.span.first and answer.span.last
            expected = car.ran(answer.span.first.timestamp() + 0.5,
                               answer.span.last.timestamp() - 0.5)
            said = {(i.app, i.generation) for i in answer.found}
            assert expected <= said, (path, answer)
            assert said <= car.ran(answer.span.first.timestamp() - 2,
                                   answer.span.last.timestamp() + 2), (path, answer)

    # sidecars: beside every finished file, none beside the one being written
    layout = Layout(car.root)
    # a quiet minute later (`now` is the pass's clock): every file but the one libpanda's
    # currentCan.csv names, which the recorder still writes
    stamped = prov.stamp_finished(layout, now=time.time() + 120)
    current = (car.root / "etc/libpanda.d/currentCan.csv").resolve()
    assert current.name.startswith("drive4_")
    finished = {p for p in (car.root / "data").iterdir()
                if not p.name.endswith(prov.SUFFIX) and p != current}
    assert set(stamped) == finished
    for path in stamped:
        side = Sidecar.model_validate_json(path.with_name(path.name + prov.SUFFIX).read_text())
        assert side.file == path.name and side.verdict == "ran"
        assert {(r.app, r.generation) for r in side.ran} == \
            {(i.app, i.generation) for i in prov.of_file(path, known).found}
    # once: a file is stamped again only if it grew since, as drive4's candump log may
    # (the recorder still writes it; only the CSV is named by currentCan.csv)
    again = prov.stamp_finished(layout, now=time.time() + 120)
    assert set(again) <= {car.root / "data" / "drive4.log"}, again

    # --desired of a finished drive, applied on a fresh root, installs the same trees
    [csv] = (car.root / "data").glob("drive2_*_CAN_Messages.csv")
    answer = prov.of_file(csv, known)
    text, _caveats = prov.desired_for(answer.found, known)
    ran = {i.app: known.software[i.software or ""] for i in answer.found}
    assert set(ran) == {"ctl-a", "recorder"}
    other = Car(car.root.parent / "other")
    (other.root / "etc/libpanda.d").mkdir(parents=True)
    (other.root / "etc/libpanda.d/vin").write_text("JTMW1RFV0KD000001\n")
    (other.root / "drive").write_text("elsewhere\n")
    try:
        apply(other, text)
        record = json.loads((other.root / "var/lib/lpam/state.json").read_text())
        assert {a["name"]: (a["commit"], a["tree"], a["params"]) for a in record["apps"]} == \
            {name: (s.commit, s.tree, s.params) for name, s in ran.items()}
    finally:
        shutdown(Layout(other.root))
    # a file from that other car is not answered from this car's timeline
    [foreign] = (other.root / "data").glob("elsewhere_*_CAN_Messages.csv")
    assert prov.of_file(foreign, known).verdict == "other vehicle"
