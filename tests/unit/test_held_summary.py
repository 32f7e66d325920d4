"""A plan that proposes nothing because of holds says so (issue 30, item 7): after
`lpam stop` or `lpam rollback` the machine differs from the desired state, so the plan
never says "The machine matches the desired state"; it names each hold and how it ends."""

from __future__ import annotations

from reconciler.core.planning.model import Observed, Targets
from reconciler.core.planning.plan import make_plan
from reconciler.core.planning.render import render
from schemas.record import HistoryEntry, Hold
from tests.unit.test_planning import NOW, app, installed, observed, repo

MATCHES = "The machine matches the desired state"


def stopped(*names: str) -> Observed:
    """`x` (and `names`) installed; each of `names` stopped by `lpam stop`."""
    seen = observed(app_rec=installed(running=False))
    apps = [a.model_copy(update={"held": True}) if a.name in names else a
            for a in seen.record.apps]
    return Observed(record=seen.record.model_copy(update={"apps": apps}),
                    repositories=seen.repositories, generations=seen.generations)


def test_an_operators_stop_is_named_not_a_match() -> None:
    plan = make_plan(Targets((repo(),), (app(),)), stopped("x"), now=NOW, lpam_version="t")
    assert plan.steps == []
    text = render(plan)
    assert MATCHES not in text, text
    assert plan.summary == ("No changes because of the holds in force: x stopped by "
                            "`lpam stop` (`lpam start x` starts it).")


def test_a_rollback_hold_is_named_with_how_it_ends() -> None:
    seen = stopped()
    entry = HistoryEntry(time="2026-11-22T00:00:00+00:00", app="x", generation="g0",
                         repository="o/apps", commit="a" * 40, path="x", tree="1" * 40,
                         result="applied")
    record = seen.record.model_copy(update={"hold": Hold(desired="f" * 64, targets=[entry])})
    plan = make_plan(Targets(()), Observed(record=record, repositories={}), now=NOW,
                     lpam_version="t", hold="held by `lpam rollback`")
    assert MATCHES not in render(plan)
    assert plan.summary == (
        "No changes because of the holds in force: `lpam rollback` holds generation g0 "
        "(a change of the desired state or `lpam apply --release` ends it).")


def test_nothing_held_still_matches() -> None:
    plan = make_plan(Targets((repo(),), (app(),)), observed(app_rec=installed()), now=NOW,
                     lpam_version="t")
    assert plan.summary == f"No changes. {MATCHES}."


def test_a_hold_on_a_file_is_released_by_applying_that_file() -> None:
    """`lpam apply --release` alone applies the default file — another desired state, or
    none: a hold against a file names that file in its way out, a hold against a
    revision of the followed repository does not (issue 30, item 13)."""
    from reconciler.core.planning.holds import release_command
    from schemas.record import DesiredRef

    seen = stopped()
    entry = HistoryEntry(time="2026-11-22T00:00:00+00:00", app="x", generation="g0",
                         repository="o/apps", commit="a" * 40, path="x", tree="1" * 40,
                         result="applied")
    held = seen.record.model_copy(update={
        "hold": Hold(desired="f" * 64, targets=[entry]),
        "desired": DesiredRef(fingerprint="f" * 64, source="/home/me/my state.yaml")})
    plan = make_plan(Targets(()), Observed(record=held, repositories={}), now=NOW,
                     lpam_version="t", hold="held by `lpam rollback`")
    assert "`lpam apply -f '/home/me/my state.yaml' --release` ends it" in str(plan.summary)
    fleet = DesiredRef(fingerprint="f" * 64, source="fleet@0123abcd/vehicles/rav4.yaml")
    assert release_command(held.model_copy(update={"desired": fleet})) == \
        "lpam apply --release"


def test_a_cut_off_apply_under_an_operators_stop_is_a_change_the_plan_names() -> None:
    """An apply killed before it started its apps, then `lpam stop`: status says the cut-off
    apply goes on with `lpam apply`; the plan, with no step left, says what that apply
    does — it records the cut-off apply finished — never "No changes" beside the stop
    (the 5,000-example consistency run, issue 30)."""
    from reconciler.core.planning.settling import settling
    from schemas.plan import Action
    from schemas.record import LastApply

    seen = stopped("x")
    cut = seen.record.model_copy(update={"last_apply": LastApply(
        time="2026-11-27T10:00:00+00:00", result="in progress", pid=4242)})
    plan = settling(make_plan(Targets((repo(),), (app(),)), stopped("x"), now=NOW,
                              lpam_version="t"), cut)
    assert plan.steps == []
    assert [(c.address, c.action) for c in plan.changes if c.action is not Action.NOOP] == \
        [("last-apply", Action.UPDATE)]
    assert plan.has_changes  # `lpam plan --detailed-exitcode` exits 2: apply writes
    assert plan.summary == (
        "Nothing to run because of the holds in force: x stopped by `lpam stop` (`lpam start "
        "x` starts it); `lpam apply` records that the last apply (cut off, began "
        "2026-11-27T10:00:00+00:00) has nothing left to do.")
    assert MATCHES not in render(plan)


def test_a_deferred_apply_the_machine_now_matches_is_ended_by_the_plan() -> None:
    from reconciler.core.planning.settling import settling
    from schemas.record import LastApply

    seen = observed(app_rec=installed())
    deferred = seen.record.model_copy(update={"last_apply": LastApply(
        time="2026-11-27T10:00:00+00:00", result="deferred", gates=["vehicle"])})
    plan = settling(make_plan(Targets((repo(),), (app(),)), seen, now=NOW,
                              lpam_version="t"), deferred)
    assert plan.summary == (
        "Nothing to run: the machine matches the desired state; `lpam apply` records that "
        "the last apply (deferred at 2026-11-27T10:00:00+00:00) has nothing left to do.")


def test_a_plan_with_steps_or_nothing_owed_is_left_as_it_is() -> None:
    from reconciler.core.planning.settling import settling
    from schemas.record import LastApply

    seen = observed(app_rec=installed())
    nothing = make_plan(Targets((repo(),), (app(),)), seen, now=NOW, lpam_version="t")
    assert settling(nothing, seen.record) == nothing  # the last apply succeeded
    steps = make_plan(Targets((repo(),), (app(params={"MODE": "9"}),)), seen, now=NOW,
                      lpam_version="t")
    assert steps.steps
    cut = seen.record.model_copy(update={"last_apply": LastApply(
        time="2026-11-27T10:00:00+00:00", result="in progress", pid=4242)})
    assert settling(steps, cut) == steps  # its steps go on from where the apply stood
