"""The options many commands share are declared once (cli.OPTIONS): same flags, defaults
and help everywhere, and `--lock-timeout` left to each use case's own default."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from reconciler.base.layout import KEEP_GENERATIONS
from reconciler.frontends import cli


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = cli._parser()
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
    assert cli._parser().parse_args(["apply"]).keep_generations == KEEP_GENERATIONS


@pytest.mark.parametrize("command", ["plan", "apply", "start", "rollback", "sync", "agent",
                                     "pin"])
def test_no_lock_timeout_given_leaves_the_use_case_its_default(command: str) -> None:
    assert cli._parser().parse_args([command]).lock_timeout is None
    assert cli._parser().parse_args([command, "--lock-timeout", "3"]).lock_timeout == 3.0


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
