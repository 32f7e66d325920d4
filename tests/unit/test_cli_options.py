"""The options many commands share are declared once (cli.OPTIONS): same flags, defaults
and help everywhere, and `--lock-timeout` left to each use case's own default."""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from pathlib import Path

import pytest

from reconciler.base.errors import Terminated
from reconciler.base.layout import KEEP_GENERATIONS
from reconciler.frontends import cli
from reconciler.frontends.console import Calling


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = cli.parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_a_shared_option_is_the_same_in_every_command() -> None:
    seen: dict[str, set[tuple[object, object]]] = {}
    for parser in subcommands().values():
        for action in parser._actions:
            if action.dest in ("script_timeout", "network_timeout", "services",
                               "keep_generations", "force"):
                seen.setdefault(action.dest, set()).add((action.default, action.help))
    assert {dest: len(kinds) for dest, kinds in seen.items()} == {
        "script_timeout": 1, "network_timeout": 1, "services": 1, "keep_generations": 1,
        "force": 1}
    assert cli.parser().parse_args(["apply"]).keep_generations == KEEP_GENERATIONS


@pytest.mark.parametrize("command", ["plan", "apply", "start", "rollback", "sync", "agent",
                                     "pin"])
def test_no_lock_timeout_given_leaves_the_use_case_its_default(command: str) -> None:
    assert cli.parser().parse_args([command]).lock_timeout is None
    assert cli.parser().parse_args([command, "--lock-timeout", "3"]).lock_timeout == 3.0


def test_pin_passes_the_lock_timeout_through(tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    from reconciler.workflow import pin

    given: list[float | None] = []

    def pinned(*args: object, lock_timeout: float | None, **kwargs: object) -> list[object]:
        given.append(lock_timeout)
        return []

    monkeypatch.setattr(pin, "pin", pinned)
    assert cli.main(["--root", str(tmp_path), "pin", "--lock-timeout", "0.5"]) == 0
    assert given == [0.5]


GLOBALS = [  # each option the README names beside --root: (flags given, dest, value read)
    (["--lock-timeout", "3"], "lock_timeout", 3.0),
    (["--script-timeout", "7"], "script_timeout", 7.0),
    (["--network-timeout", "9"], "network_timeout", 9.0),
    (["--services", "systemd"], "services", "systemd"),
    (["--keep-generations", "5"], "keep_generations", 5),
]


@pytest.mark.parametrize(("flags", "dest", "value"), GLOBALS)
@pytest.mark.parametrize("command", ["apply", "sync", "rollback", "plan", "status", "logs"])
def test_a_global_option_is_read_before_the_command_as_after_it(
    command: str, flags: list[str], dest: str, value: object,
) -> None:
    """`lpam --root R --services systemd apply` was refused ("invalid choice: 'systemd'");
    and had it been read, the subcommand's own default would have overwritten it (issue 30,
    item 12). Before the command it is read for every command, as --root is; after it,
    where the command takes it; written in both places, the one after the command wins."""
    parser = cli.parser()
    before = parser.parse_args(["--root", "/r", *flags, command])
    assert getattr(before, dest) == value and before.root == "/r"
    if any(a.dest == dest for a in subcommands()[command]._actions):
        after = parser.parse_args([command, "--root", "/r", *flags])
        assert getattr(after, dest) == value
        other = ["--services", "supervisor"] if dest == "services" else [flags[0], "2"]
        both = parser.parse_args([*flags, command, *other])
        assert getattr(both, dest) == parser.parse_args([command, *other]).__dict__[dest]
    default = getattr(parser.parse_args([command]), dest)
    assert default == {"lock_timeout": None, "script_timeout": 600.0, "network_timeout": 60.0,
                       "services": None, "keep_generations": KEEP_GENERATIONS}[dest]


def test_lpam_runs_a_command_given_a_global_option_before_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:
    seen: list[argparse.Namespace] = []

    def apply(args: argparse.Namespace, layout: object) -> int:
        seen.append(args)
        return 0

    monkeypatch.setitem(cli.COMMANDS, "apply", apply)
    argv = ["--root", str(tmp_path), "--services", "supervisor", "--script-timeout", "4",
            "--network-timeout", "5", "--lock-timeout", "6", "--keep-generations", "2",
            "apply", "--yes"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    [args] = seen
    assert (args.services, args.script_timeout, args.network_timeout, args.lock_timeout,
            args.keep_generations, args.yes) == ("supervisor", 4.0, 5.0, 6.0, 2, True)


def test_a_suggested_command_is_spelled_for_the_root_it_acts_on() -> None:
    """The layers below write `lpam apply`; on a root other than / the face adds the root
    (absolute) and a service manager named on the command line, once (issue 30, item 13)."""
    from reconciler.frontends.console import Calling

    text = "run `lpam apply --release`, or `lpam start`; not lpam itself"
    assert Calling.of(Path("/")).spell(text) == text
    sandbox = Calling.of(Path("/tmp/my root"), services="supervisor")
    assert sandbox.spell(text) == (
        "run `lpam --root '/tmp/my root' --services supervisor apply --release`, or "
        "`lpam --root '/tmp/my root' --services supervisor start`; not lpam itself")
    assert sandbox.spell(sandbox.spell(text)) == sandbox.spell(text)
    said = "held by `lpam rollback`: nothing is proposed"  # a deed, not a suggestion
    assert sandbox.spell(said) == said


@pytest.mark.parametrize(("ending", "code"), [(KeyboardInterrupt, 0), (Terminated, 143)])
def test_ctrl_c_ends_a_follow_quietly(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    ending: type[BaseException], code: int,
) -> None:
    """Ctrl-C is how `lpam logs -f` ends: no "interrupted: nothing was changed" under the
    app's output (issue 30, item 14)."""
    from reconciler.workflow import logs

    def following(machine: object, shown: object) -> Iterator[str]:
        yield "tick 3"
        raise ending

    monkeypatch.setattr("signal.signal", lambda *args: None)  # pytest's handlers stay
    monkeypatch.setattr(logs, "app_logs", lambda *args: logs.Shown(["tick 1", "tick 2"],
                                                                   unit="x.service"))
    monkeypatch.setattr(logs, "new_output", following)
    assert cli.main(["--root", str(tmp_path), "logs", "-f", "-n", "2"]) == code
    assert capsys.readouterr() == ("tick 1\ntick 2\ntick 3\n", "")


def test_status_json_spells_its_commands_as_the_table_does(tmp_path: Path) -> None:
    """`status --json` says the table's sentences (holds, hints): a reader that shows one
    must be able to run it as shown, here with the sandbox's root."""
    calling = Calling.of(tmp_path / "root")
    value = {"holds": [{"ends": "with `lpam start` or `lpam apply --release`"}],
             "serial": 3, "app": None}
    spelled = calling.spell_values(value)
    assert spelled["holds"][0]["ends"] == (
        f"with `lpam --root {tmp_path / 'root'} start` or "
        f"`lpam --root {tmp_path / 'root'} apply --release`")
    assert spelled["serial"] == 3 and spelled["app"] is None
    assert Calling.of(Path("/")).spell_values(value) == value  # on a car: as written
