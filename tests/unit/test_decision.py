"""One decision per app (core/planning/decision.py): what the plan says of an app and the
steps it runs for it come from one value, so they cannot disagree — over every status,
hold, proof, unit state and change of parameters an installed app can be in."""

from __future__ import annotations

from itertools import product
from typing import Any, Literal

from reconciler.base.unit import UnitState
from reconciler.core.planning.decision import (
    Decision,
    Finish,
    Held,
    NotRunning,
    Reconfigure,
    Running,
    StartedOutside,
    Unsupervised,
    decide,
)
from reconciler.core.planning.model import AppTarget, GenerationKey, generation_id
from schemas.plan import Action, StepKind
from schemas.record import AppRecord

TREE = "1" * 40
STATUSES = ["installing", "installed", "starting", "running", "stopping", "uninstalling"]


def installed(status: str, *, held: bool, good: bool, params: dict[str, str]) -> AppRecord:
    return AppRecord(name="x", repository="o/apps", commit="a" * 40, tree=TREE, path="x",
                     params=params, generation=generation_id(TREE, {}), status=status,
                     held=held, good=good, service="lpam-app-x")


def wanted(params: dict[str, str]) -> AppTarget:
    return AppTarget(name="x", repository="o/apps", commit="a" * 40, path="x", tree=TREE,
                     params=params)


ACTIVE: tuple[Literal["active", "inactive", "failed", "activating"], ...] = (
    "active", "inactive", "failed", "activating")
UNITS: list[UnitState | None] = [None, *(
    UnitState("lpam-app-x", known=known, active=active, supervised=supervised)
    for known, active, supervised in product((True, False), ACTIVE, (True, False)))]


def kinds(decision: Decision) -> list[StepKind]:
    return [s.kind for s in decision.steps]


def test_what_the_plan_says_of_an_installed_app_is_what_its_steps_do() -> None:
    """Every case there is (1,632 of them), each checked: the space is small enough."""
    cases = product(STATUSES, (True, False), (True, False), UNITS, (True, False),
                    (True, False))
    for status, held, good, live, new_params, start in cases:
        check(status, held, good, live, new_params, start)


def check(status: str, held: bool, good: bool, live: UnitState | None, new_params: bool,
          start: bool) -> None:
    old = installed(status, held=held, good=good, params={"K": "1"})
    new = wanted({"K": "2"} if new_params else {"K": "1"})
    decision = decide(old, new, frozenset({GenerationKey.of("x", old.generation)}), live,
                      start=start)
    reason, steps = decision.reason, kinds(decision)
    change = decision.change()
    assert change.address == "app.x" and change.reason == reason.said()
    # a no-op runs nothing; anything else runs something
    assert (decision.action is Action.NOOP) == (steps == []), (reason, steps)
    # the same generation is never reinstalled from scratch
    assert StepKind.UNINSTALL not in steps and StepKind.STAGE not in steps
    said = change.reason
    if isinstance(reason, Reconfigure):
        assert StepKind.CONFIGURE in steps
        assert (StepKind.INSTALL in steps) == reason.reinstall
        assert ("no install script runs" in said) == (StepKind.INSTALL not in steps)
        assert (StepKind.START in steps) == start
    else:
        assert StepKind.CONFIGURE not in steps
    if isinstance(reason, Held):
        assert StepKind.START not in steps and reason.operator == old.held
        assert old.held or not start  # an operator's stop holds, or nothing is started
        assert (StepKind.STOP in steps) == reason.may_run
        assert (StepKind.INSTALL in steps) == reason.reinstall
    if isinstance(reason, Unsupervised):
        assert steps[:2] == [StepKind.STOP, StepKind.START] and "stopped, then started" in said
    if isinstance(reason, NotRunning):
        assert steps[0] is StepKind.START and said.endswith(("start", "settle window"))
    if isinstance(reason, StartedOutside):
        assert steps == [] and change.warnings
    if isinstance(reason, (Running, Finish, NotRunning)):
        assert (StepKind.VERIFY in steps) == reason.unproven
        assert ("health check" in said) == reason.unproven
    if isinstance(reason, Finish):
        expected: dict[str, Any] = {
            "installed": [StepKind.START], "starting": [StepKind.START],
            "installing": [StepKind.INSTALL, StepKind.START],
            "stopping": [StepKind.STOP, StepKind.START],
            "uninstalling": [StepKind.INSTALL, StepKind.START]}
        assert steps[:len(expected[reason.status])] == expected[reason.status]
    if not start:  # an operator's stop, a rollback to a stopped app: nothing starts
        assert StepKind.START not in steps and StepKind.VERIFY not in steps


def test_new_parameters_for_an_app_whose_install_was_cut_off_say_it_runs_again() -> None:
    """The field trial's plan said "no install script runs" above an `install:` step."""
    old = installed("installing", held=False, good=True, params={"K": "1"})
    decision = decide(old, wanted({"K": "2"}), frozenset({GenerationKey.of("x", old.generation)}))
    assert kinds(decision)[:2] == [StepKind.CONFIGURE, StepKind.INSTALL]
    said = decision.change().reason
    assert "no install script runs" not in said
    assert "install script" in said and "runs again" in said


def test_an_app_that_leaves_names_what_it_shares_with_each_heir() -> None:
    """A field trial's switch said pandarecord is uninstalled before joystick2toyota, "which
    claims what it claims (panda, service:pandarecord)": only the panda is shared."""
    old = installed("running", held=False, good=True, params={}).model_copy(
        update={"resources": ["panda", "service:pandarecord"]})
    heir = AppTarget(name="joystick2toyota", repository="o/apps", commit="a" * 40,
                     path="j", tree=TREE, resources=frozenset({"panda", "service:simplesend"}))
    said = decide(old, None, frozenset(), heirs=[heir]).change().reason
    assert said.endswith("before joystick2toyota, which claims what it claims (panda), is "
                         "installed")
    other = AppTarget(name="tracker", repository="o/apps", commit="a" * 40, path="t",
                      tree=TREE, resources=frozenset({"service:pandarecord"}))
    said = decide(old, None, frozenset(), heirs=[heir, other]).change().reason
    assert "before joystick2toyota, tracker, which claim what it claims (panda, " \
        "service:pandarecord), are installed" in said
