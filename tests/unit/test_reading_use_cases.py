"""The read-only use cases the CLI only renders: history's current mark, `logs -f`'s new
lines, the import's refusal to overwrite, and the operator actions as a closed set."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError, LpamError
from reconciler.base.layout import Layout
from reconciler.engine.records.state import read_record, write_record
from reconciler.workflow.history import history
from reconciler.workflow.importing import import_legacy
from reconciler.workflow.logs import Shown, new_output, seen_up_to
from reconciler.workflow.machine import Machine
from schemas.operator import OperatorAction
from schemas.record import Actor, HistoryEntry
from tests.records import sole
from tests.unit.test_gate_execution import running_x


def test_history_marks_the_installed_generation_as_applied(tmp_path: Path) -> None:
    world = running_x(tmp_path)
    record = read_record(world.layout)
    assert len(record.apps) == 1
    now = HistoryEntry.of(sole(record), time="t2", result="applied")
    failed = HistoryEntry.of(sole(record), time="t3", result="failed")
    other = now.model_copy(update={"generation": "other", "time": "t1"})
    write_record(world.layout, record.model_copy(update={"history": [other, now, failed]}))
    assert [(m.entry.time, m.current) for m in history(world.layout)] == [
        ("t1", False), ("t2", True), ("t3", False)]
    assert history(Layout(tmp_path / "empty")) == []


class Output:
    """A service manager whose unit printed `said`, one more batch each time it is asked."""

    def __init__(self, *said: list[str]) -> None:
        self.said = list(said)

    def logs(self, name: str, lines: int = 20) -> list[str]:
        return self.said.pop(0)


def test_following_prints_only_what_is_new(tmp_path: Path) -> None:
    assert seen_up_to(["a", "b", "c"], ["b", "c", "d"]) == 2
    assert seen_up_to(["a"], ["x"]) == 0
    machine = Machine(Layout(tmp_path),
                      given_services=Output(["b", "c", "d"], ["d", "e"]))  # type: ignore[arg-type]
    lines = new_output(machine, Shown(["a", "b", "c"], unit="x.service"), sleep=lambda s: None)
    assert [next(lines), next(lines)] == ["d", "e"]
    with pytest.raises(LpamError, match="cannot follow"):
        next(new_output(machine, Shown(["a"]), sleep=lambda s: None))


class Growing:
    """A unit's log file that grows by one line each second, read from its end as
    supervisord's log and journalctl are: the last `lines` lines."""

    def __init__(self, lines: list[str]) -> None:
        self.file = list(lines)

    def logs(self, name: str, lines: int = 20) -> list[str]:
        return self.file[-lines:]

    def second(self, seconds: float) -> None:
        self.file.append(f"line {len(self.file) + 1}")


def test_following_after_n_lines_prints_only_the_lines_that_come_after_them(
    tmp_path: Path,
) -> None:
    """`lpam logs APP -f -n 2`: the last 2 lines, then only what the app prints next —
    not the whole file again from its first line (issue 30, item 11)."""
    log = Growing([f"line {n}" for n in range(1, 11)])
    machine = Machine(Layout(tmp_path), given_services=log)  # type: ignore[arg-type]
    shown = Shown(log.logs("x.service", 2), unit="x.service")
    assert shown.lines == ["line 9", "line 10"]
    lines = new_output(machine, shown, sleep=log.second)
    assert [next(lines) for _ in range(3)] == ["line 11", "line 12", "line 13"]
    # with several apps, each app's own lines are followed from where they were shown
    shown = Shown([], units={"a": "x.service"}, seen={"a": log.logs("x.service", 3)})
    lines = new_output(machine, shown, sleep=log.second)
    assert [next(lines) for _ in range(2)] == ["a | line 14", "a | line 15"]


def test_the_import_never_overwrites(tmp_path: Path) -> None:
    taken = tmp_path / "desired.yaml"
    taken.write_text("mine\n")
    etc = tmp_path / "libpanda.d"
    etc.mkdir()
    (etc / "app-manifest.yaml").write_text("\n")
    (etc / "app").write_text("None\n")
    with pytest.raises(ConfigError, match="will not overwrite"):
        import_legacy(Layout(tmp_path), etc, output=taken)
    assert taken.read_text() == "mine\n"
    written = tmp_path / "new.yaml"
    assert import_legacy(Layout(tmp_path), etc, output=written) == written.read_text()


def test_operator_actions_are_a_closed_set() -> None:
    assert [str(a) for a in OperatorAction] == ["start", "stop", "restart"]
    with pytest.raises(ValueError):
        OperatorAction("kill")


def test_history_is_a_table_whose_columns_stay_put(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`lpam history` had no header, and a long repository name pushed the rest of its
    row to the right (issue 30, item 14): a header, and each column at one place."""
    from reconciler.frontends import cli

    world = running_x(tmp_path)
    record = read_record(world.layout)
    now = HistoryEntry.of(sole(record), time="2026-11-27T10:00:00+00:00", result="applied",
                          by=Actor(kind="phone", id="AA:BB:CC:DD:EE:FF", name="Pixel 7"))
    other = now.model_copy(update={"generation": "0123456789ab-cdef0123",
                                   "time": "2026-11-26T09:00:00+00:00",
                                   "repository": "a-much-longer-repository-name",
                                   "params": {"RATE_HZ": "10"},
                                   "by": Actor(kind="user", id="alice", via="lpam")})
    write_record(world.layout, record.model_copy(update={"history": [other, now]}))
    monkeypatch.setattr("signal.signal", lambda *args: None)
    assert cli.main(["--root", str(world.layout.root), "history"]) == 0
    header, *rows = capsys.readouterr().out.splitlines()
    assert header.split() == ["Now", "Time", "App", "Generation", "Repository", "Commit",
                              "Result", "By", "Params"]
    for name in ("Time", "App", "Generation", "Repository", "Commit", "Result", "By",
                 "Params"):
        at = header.index(name)
        assert all(row[at - 1] == " " and row[at] != " " for row in rows), (name, rows)
    assert rows[0].split()[5:] == ["applied", "alice", "(lpam)", "RATE_HZ=10"]
    assert rows[1].startswith("*") and rows[1].split()[-1] == "-"  # installed now
    assert "phone AA:BB:CC:DD:EE:FF (Pixel 7)" in rows[1]


def test_a_record_from_before_version_8_reads_and_its_history_names_no_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A car upgraded from an lpam that did not record who made a change: its history
    reads, says `-` under By (nothing is guessed), and a record written again is version
    8 with the history as it was."""
    import json

    import migrations
    from reconciler.base.loading import load
    from reconciler.frontends import cli

    fixture = Path(migrations.__file__).parent / "fixtures" / "state-record" / "v7_to_v8" / \
        "deferred-several.before.yaml"
    old = load(fixture).data
    layout = Layout(tmp_path)
    layout.state_record.parent.mkdir(parents=True)
    layout.state_record.write_text(json.dumps(old))
    monkeypatch.setattr("signal.signal", lambda *args: None)
    assert cli.main(["--root", str(tmp_path), "history"]) == 0
    header, *rows = capsys.readouterr().out.splitlines()
    at = header.index("By")
    assert [row[at:].split()[0] for row in rows] == ["-", "-"]
    assert cli.main(["--root", str(tmp_path), "history", "--json"]) == 0
    assert [e.get("by") for e in json.loads(capsys.readouterr().out)] == [None, None]
    record = read_record(layout)
    assert record.last_apply is not None and record.last_apply.result == "deferred"
    write_record(layout, record)
    again = json.loads(layout.state_record.read_text())
    assert again["version"] == 8 and again["history"] == old["history"]
