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
