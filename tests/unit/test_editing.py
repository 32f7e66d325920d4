"""Edits of the desired state (workflow/editing.py) and the shim's pure parts
(reconciler/frontends/shim.py): a round trip keeps comments, order and `version:`; a bad value is
refused before any lock (it never waits on another apply) and changes nothing; the
command line is read as LPAM's getopts read it; `-d`'s cells survive bluezone's decoding.

These need no network: a desired state with no repository plans without one.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from reconciler.base.errors import CatalogError, ConfigError, LockError, LpamError
from reconciler.base.layout import Layout
from reconciler.engine.execution.lock import apply_lock
from reconciler.frontends.shim import Command, UsageError, bluezone_safe, parse, table
from reconciler.workflow import editing
from reconciler.workflow.applying import ApplyOptions
from reconciler.workflow.events import Event, Planned
from reconciler.workflow.machine import Machine
from tests.records import lpam_row

TEXT = """\
# the car's desired state: keep this comment
version: 1   # the format
repositories: []
app:
  name: alpha  # the app of the week
  params: {RATE: "10"}
gates: {windows: ["00:00-23:59"]}
# the end
"""


def quiet(event: Event) -> None:
    pass


@pytest.fixture
def machine(tmp_path: Path) -> Machine:
    machine = Machine.at(Layout(tmp_path / "root"))
    path = machine.layout.desired_state
    path.parent.mkdir(parents=True)
    path.write_text(TEXT)
    return machine


def options(wait: float = 5.0) -> ApplyOptions:
    return ApplyOptions(lock_timeout=wait)


def test_no_app_is_written_with_comments_order_and_version_kept(machine: Machine) -> None:
    done = editing.enable_app(machine, None, by="test", options=options(), report=quiet)
    assert done.changed and done.applied.steps == 0  # nothing on the machine changes
    text = machine.layout.desired_state.read_text()
    assert text.startswith("# the car's desired state: keep this comment\nversion: 1   #")
    assert "# the end" in text and 'windows: ["00:00-23:59"]' in text
    assert [line.split(":")[0] for line in text.splitlines() if line[:1].isalpha()] == \
        ["version", "repositories", "app", "gates"]
    assert "alpha" not in text
    again = editing.enable_app(machine, None, by="test", options=options(), report=quiet)
    assert not again.changed and machine.layout.desired_state.read_text() == text


def test_an_edit_composes_the_file_once_and_its_result_once(machine: Machine) -> None:
    """The tree validated is the tree edited (quotes kept, as the test above holds): the
    file is composed as YAML once, and the edited text once, to validate it (issue 32
    item 2; a phone's edit on a Pi composed the file twice)."""
    from unittest import mock

    from ruamel.yaml.composer import Composer

    with mock.patch.object(Composer, "get_single_node", autospec=True,
                           side_effect=Composer.get_single_node) as composed:
        done = editing.enable_app(machine, None, by="test", options=options(), report=quiet)
    assert done.changed and "alpha" not in machine.layout.desired_state.read_text()
    assert composed.call_count == 2


def test_a_plan_time_refusal_leaves_the_file_byte_identical(machine: Machine) -> None:
    before = machine.layout.desired_state.read_bytes()
    with pytest.raises(CatalogError, match="gamma is not in the catalog"):
        editing.enable_app(machine, "gamma", by="test", options=options(), report=quiet)
    assert machine.layout.desired_state.read_bytes() == before


@pytest.mark.parametrize(("call", "expected"), [
    (lambda m, o: editing.enable_app(m, "--upload-pack=x", by="t", options=o, report=quiet),
     "starts with '-'"),
    (lambda m, o: editing.enable_app(m, "a b", by="t", options=o, report=quiet),
     "whitespace"),
    (lambda m, o: editing.enable_app(m, "a\x1b[2J", by="t", options=o, report=quiet),
     "control"),
    (lambda m, o: editing.enable_app(m, "a/b", by="t", options=o, report=quiet),
     "app names use"),
    (lambda m, o: editing.add_repository(m, "x/..", None, by="t", options=o, report=quiet),
     "'..'"),
    (lambda m, o: editing.add_repository(m, "o/r", "-f", by="t", options=o, report=quiet),
     "starts with '-'"),
    (lambda m, o: editing.add_repository(m, "o/r", "a@{1}", by="t", options=o, report=quiet),
     "not a valid branch"),
    (lambda m, o: editing.add_repository(m, "git@evil:x", None, by="t", options=o,
                                         report=quiet), "GitHub repository"),
    (lambda m, o: editing.add_repository(m, "o_x/r", None, by="t", options=o, report=quiet),
     "GitHub repository"),
    (lambda m, o: editing.remove_repository(m, "o/r", by="t", options=o, report=quiet),
     "not in the desired state"),
    (lambda m, o: editing.set_params(m, "beta", {}, by="t", options=o, report=quiet),
     "beta is not the desired app"),
    (lambda m, o: editing.set_params(m, "alpha", {"LD_PRELOAD": "x"}, by="t", options=o,
                                     report=quiet), "loader"),
    (lambda m, o: editing.set_params(m, "alpha", {"A": "x\ny"}, by="t", options=o,
                                     report=quiet), "control character"),
    (lambda m, o: editing.set_params(m, "alpha", {"A": "x" * 5000}, by="t", options=o,
                                     report=quiet), "longer than 4096"),
])
def test_bad_values_are_refused_before_the_lock(machine: Machine, call: object,
                                                expected: str) -> None:
    before = machine.layout.desired_state.read_bytes()
    with apply_lock(machine.layout, timeout=0):  # another apply runs
        started = time.monotonic()
        with pytest.raises(LpamError, match=expected) as caught:
            call(machine, options(wait=30))  # type: ignore[operator]
        assert time.monotonic() - started < 5  # refused at once, not after the lock's wait
    assert not isinstance(caught.value, LockError)
    assert machine.layout.desired_state.read_bytes() == before


def test_a_sound_edit_waits_for_the_lock_and_says_who_holds_it(machine: Machine) -> None:
    before = machine.layout.desired_state.read_bytes()
    with apply_lock(machine.layout, timeout=0), pytest.raises(LockError):
        editing.enable_app(machine, None, by="t", options=options(wait=0.3), report=quiet)
    assert machine.layout.desired_state.read_bytes() == before


def test_an_older_format_is_refused_not_mixed(machine: Machine) -> None:
    path = machine.layout.desired_state
    path.write_text("version: 0.0\nrepositories: {}\ncurrent: None\n")
    with pytest.raises(ConfigError, match="only a version 1 desired state"):
        editing.enable_app(machine, None, by="t", options=options(), report=quiet)


def test_a_params_edit_refused_at_plan_time_changes_nothing(machine: Machine) -> None:
    with pytest.raises(CatalogError):  # no repository offers alpha: refused at plan time
        editing.set_params(machine, "alpha", {"RATE": "20"}, by="t", options=options(),
                           report=quiet)
    assert machine.layout.desired_state.read_text() == TEXT


def test_getopts_reading() -> None:
    assert parse(["-dc"]).actions == [("d", None), ("c", None)]
    assert parse(["-iAPP"]).actions == [("i", "APP")]
    assert parse(["-ci", "APP", "-l"]).actions == [("c", None), ("i", "APP"), ("l", None)]
    both = parse(["-g", "o/r", "-bdev", "-u"])
    assert (both.repository, both.branch, both.actions) == ("o/r", "dev", [("u", None)])
    assert parse(["-h"]).help and parse(["-d", "--"]).actions == [("d", None)]
    for argv, message in [
        ([], "no flag"), (["-b", "main"], "goes with -g"), (["-x"], "unknown option -x"),
        (["-i"], "needs a value"), (["-i", "--upload-pack=x"], "refused"),
        (["-i-x"], "refused"), (["-r", ""], "refused"), (["-c", "word"], "unexpected"),
        (["-g", "a/b", "-g", "c/d"], "twice"), (["-", "-c"], "unexpected"),
    ]:
        with pytest.raises(UsageError, match=message):
            parse(argv)
    assert isinstance(parse(["-p"]), Command)


def bluezone(text: str) -> str:
    """bluezone.py's decoding of LPAM's output (app_info)."""
    return text.encode("utf-8").decode("utf-8").encode("latin1").decode("unicode_escape") \
        .encode("latin1").decode("utf8")


@pytest.mark.parametrize("text", ["plain", "Données → CAN 🚗", r"C:\new\table", "x\\y"])
def test_cells_survive_bluezones_decoding(text: str) -> None:
    cell = bluezone_safe(text)
    assert cell.isascii() and "\t" not in cell and "\n" not in cell
    assert bluezone(cell) == text


def test_a_tab_or_newline_in_a_value_cannot_split_bluezones_columns() -> None:
    row = lpam_row(repository="o/r", branch="main", app="a", service="", enabled=True,
                   running=False, description="one\ttwo\nthree")
    out = table([row])
    lines = bluezone(out).split("\n")[1:-1]
    assert lines == ['o/r\tmain\ta\tnone\tyes\tno\t"one two three"']  # no service: said


def test_an_edit_never_writes_over_a_change_made_while_it_waited(machine: Machine) -> None:
    """Two frontends at once: the desired state changes after this edit read it (here
    while its plan is made, under the lock); writing its text would undo that change."""
    path = machine.layout.desired_state
    meddled = TEXT.replace("alpha", "beta")

    def meddle(event: Event) -> None:
        if isinstance(event, Planned):
            path.write_text(meddled)

    with pytest.raises(LpamError, match="changed while this edit waited"):
        editing.enable_app(machine, None, by="test", options=options(), report=meddle)
    assert path.read_text() == meddled


def test_a_bug_is_one_line_and_its_traceback_goes_to_the_debug_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from reconciler.frontends import shim

    def broken(machine: Machine, command: Command) -> None:
        raise RuntimeError("a bug")

    monkeypatch.setenv("LPAM_ROOT", str(tmp_path))
    monkeypatch.setattr(shim, "run", broken)
    monkeypatch.setattr("signal.signal", lambda *args: None)  # pytest's handlers stay
    assert shim.main(["-c"]) == 1
    out = capsys.readouterr()
    assert out.out == "" and out.err.count("\n") == 1
    assert out.err.startswith("libpanda-app-manager: error: internal error; details in ")
    assert "RuntimeError: a bug" in Layout(tmp_path).debug_log.read_text()
    assert shim.main(["-h"]) == 0 and "usage: libpanda-app-manager" in capsys.readouterr().out
    assert shim.main(["-q"]) == 2
    assert capsys.readouterr().err == \
        "libpanda-app-manager: error: unknown option -q (see libpanda-app-manager -h)\n"
