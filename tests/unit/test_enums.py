"""lpam's closed string sets read the same on every Python it runs on (3.9 to the newest):
plans, status lines and JSON show the value, never "Phase.CUTOVER"."""

from __future__ import annotations

import json

from schemas.plan import Action, Phase, StepKind


def test_members_print_and_format_as_their_value() -> None:
    assert str(Phase.CUTOVER) == "cutover"
    assert f"[{Phase.CUTOVER}] {StepKind.VERIFY}:app" == "[cutover] verify:app"
    assert f"{Action.NOOP:>7}|" == "  no-op|"
    assert "%s" % StepKind.START == "start"  # noqa: UP031 - the old spelling, still used


def test_members_are_their_strings() -> None:
    assert StepKind("checkout") is StepKind.CHECKOUT
    text: str = "checkout"  # as read from a saved plan
    assert text == StepKind.CHECKOUT and isinstance(StepKind.CHECKOUT, str)
    assert json.dumps({"phase": Phase.PREPARE}) == '{"phase": "prepare"}'
    assert {"checkout": 1}[StepKind.CHECKOUT] == 1
