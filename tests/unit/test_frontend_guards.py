"""How each front end ends a request that did not end well, through the one guard they
share (reconciler/frontends/console.py `guarded`): `lpam` and `libpanda-app-manager` say
one line on stderr and exit with the code of what ended it; the Bluetooth service answers
the phone and goes on. A bug's traceback goes to the debug log, never to the user.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from reconciler import __version__
from reconciler.adapters.bluez.shape import Characteristic
from reconciler.base.errors import ConfigError, Deferred, LpamError, Terminated
from reconciler.base.layout import Layout
from reconciler.frontends import cli, shim
from reconciler.frontends.ble.bridge import Bridge
from reconciler.frontends.ble.temperature import Thermometer
from reconciler.frontends.console import debug_log, guarded
from reconciler.workflow.machine import Machine

SHIM = "libpanda-app-manager: error: "
RESUME_SHIM = "interrupted: lpam recorded where it stood; `lpam apply` goes on from there"

# what ends the request -> (exit code, `lpam status`'s stderr, the shim's stderr)
ENDINGS: dict[str, tuple[BaseException, int, str, str]] = {
    "error": (LpamError("boom", hint="do this"), 1,
              "error: boom\n  hint: do this\n", f"{SHIM}boom (hint: do this)\n"),
    "document": (ConfigError("bad key", path=Path("/x/d.yaml"), line=3, column=4, hint="fix"),
                 1, "error: /x/d.yaml:3:4: bad key\n  hint: fix\n",
                 f"{SHIM}/x/d.yaml:3:4: bad key (hint: fix)\n"),
    "deferred": (Deferred("gates closed"), 75, "deferred: gates closed\n",  # not a failure
                 "libpanda-app-manager: deferred: gates closed\n"),
    "reader-left": (BrokenPipeError(), 0, "", ""),
    "ctrl-c": (KeyboardInterrupt(), 130, "interrupted: nothing was changed\n",
               f"{SHIM}{RESUME_SHIM}\n"),
    "sigterm": (Terminated(), 143, "interrupted: nothing was changed\n",
                f"{SHIM}{RESUME_SHIM}\n"),
}


def raising(exc: BaseException) -> Callable[..., Any]:
    def run(*_: object) -> Any:
        raise exc

    return run


@pytest.fixture(autouse=True)
def _root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LPAM_ROOT", str(tmp_path))
    monkeypatch.setattr("signal.signal", lambda *args: None)  # pytest's handlers stay


@pytest.mark.parametrize("ending", ENDINGS)
def test_each_ending_is_one_line_and_its_exit_code(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    ending: str,
) -> None:
    exc, code, lpam_says, shim_says = ENDINGS[ending]
    monkeypatch.setitem(cli.COMMANDS, "status", raising(exc))
    assert cli.main(["--root", str(tmp_path), "status"]) == code
    assert capsys.readouterr() == ("", lpam_says)
    monkeypatch.setattr(shim, "run", raising(exc))
    assert shim.main(["-c"]) == code
    assert capsys.readouterr() == ("", shim_says)
    assert not Layout(tmp_path).debug_log.exists()


def test_an_interrupted_change_says_how_to_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setitem(cli.COMMANDS, "apply", raising(Terminated()))
    assert cli.main(["--root", str(tmp_path), "apply"]) == 143
    assert capsys.readouterr().err == (
        "interrupted: lpam recorded where it stood (a script under way is stopped with its "
        f"whole process group); run `lpam --root {tmp_path} apply` to resume\n")


def test_a_bug_points_to_its_traceback_in_the_debug_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:
    log = Layout(tmp_path).debug_log
    monkeypatch.setitem(cli.COMMANDS, "status", raising(RuntimeError("a bug")))
    assert cli.main(["--root", str(tmp_path), "status"]) == 1
    assert capsys.readouterr() == (
        "", f"error: internal error in lpam {__version__}; details in {log}\n")
    monkeypatch.setattr(shim, "run", raising(RuntimeError("a bug")))
    assert shim.main(["-c"]) == 1
    assert capsys.readouterr() == ("", f"{SHIM}internal error; details in {log}\n")
    assert log.read_text().count("RuntimeError: a bug") == 2


@pytest.mark.parametrize("exc", [RuntimeError("a bug"), LpamError("boom"), BrokenPipeError()])
def test_the_bluetooth_service_answers_a_bug_and_goes_on(tmp_path: Path,
                                                         exc: Exception) -> None:
    """The phone's answers name each request's failure themselves: whatever reaches the
    bridge's guard, an LpamError too, is a bug, said to the phone and logged."""
    lines: list[str] = []
    sent: list[tuple[Characteristic, bytes]] = []
    machine = Machine.at(Layout(tmp_path))
    bridge = Bridge(machine, lambda char, value: sent.append((char, value)),
                    thermometer=Thermometer(machine.layout.thermal_zone),
                    log=lines.append, bug=lambda: debug_log(machine.layout))
    bridge._answer = raising(exc)  # type: ignore[method-assign]
    bridge.write(Characteristic.COMMAND, b"A", None)
    assert bridge.stop(10)
    name = type(exc).__name__
    status = f"Internal error in lpam ({name}); details in its debug log"
    log = machine.layout.debug_log
    assert lines[1:] == [f"internal error on <Command.INFO: 'A'>: {exc!r}; details in {log}",
                         f"status: {status}"]
    assert sent == [(Characteristic.STATUS, status.encode())]
    assert f"{name}" in log.read_text()


def test_an_interrupt_passes_through_a_guard_that_names_no_answer_for_it() -> None:
    with pytest.raises(KeyboardInterrupt):
        guarded(raising(KeyboardInterrupt()), bug=lambda: "nowhere",
                internal=lambda exc, where: 1)


def test_a_long_commands_progress_shows_it_whole_and_cuts_its_output_at_the_end(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Progress lines cut a command in the middle ("pip install a b … y z"), which reads
    as a command that does not exist (issue 30, item 14)."""
    from reconciler.frontends.console import Terminal
    from reconciler.workflow.events import Output

    command = "$ pip install " + " ".join(f"package-{n}" for n in range(30))
    said = "Collecting " + " ".join(f"dependency-{n}" for n in range(30))
    terminal = Terminal()
    clock = iter([0.0, 10.0])
    terminal._clock = lambda: next(clock)
    terminal(Output(command))
    terminal(Output(said))
    shown, output = capsys.readouterr().out.splitlines()
    assert shown == f"      {command}"
    assert output.startswith("      … 10 s: Collecting dependency-0 dependency-1")
    assert output.endswith("…") and len(output) < len(said)


LANDS_IN_A_CALLBACK = """
import os, signal, sys, time, weakref
from reconciler.base.errors import Terminated
from reconciler.frontends.console import raise_signals_where_lpam_stands

raise_signals_where_lpam_stands()

class Thing:
    pass

def callback(_):  # as importlib's module locks do: Python cannot raise out of this
    os.kill(os.getpid(), getattr(signal, sys.argv[1]))
    for _ in range(100000):
        pass  # the signal's handler runs here, inside the callback

thing = Thing()
ref = weakref.ref(thing, callback)
try:
    del thing
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        time.sleep(0.001)
    print("went on as if not asked to stop")
except (Terminated, KeyboardInterrupt) as exc:
    print(f"stopped where it stood: {type(exc).__name__}")
"""


@pytest.mark.parametrize(("sig", "raised"), [("SIGTERM", "Terminated"),
                                             ("SIGINT", "KeyboardInterrupt")])
def test_an_interrupt_that_lands_in_a_callback_stops_lpam_and_prints_no_traceback(
        sig: str, raised: str) -> None:
    """A SIGTERM that fell inside importlib's module-lock callback printed "Exception
    ignored … Traceback … Terminated" under `lpam apply`, which then went on (the fault
    test's round 1 in a fresh clone). It stops lpam where it stands instead, quietly."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", LANDS_IN_A_CALLBACK, sig],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.stdout.strip() == f"stopped where it stood: {raised}"
    assert done.stderr == ""
