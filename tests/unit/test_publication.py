"""The pure rules of status publishing (reconciler/core/publication.py): what counts as a
change, when the heartbeat is due, how long a status branch grows. The real git daemon
counting connections and commits is tests/integration/test_fleet_scale.py."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from typing import Any

import pytest

from reconciler.core.publication import HISTORY, due, fingerprint, keeps_parent
from schemas.agent import AgentStatus, Attempt, Publication, Result
from schemas.fleet import PublishedApp

REV, NEW = "a" * 40, "b" * 40
T0 = datetime(2026, 11, 20, 10, 0, tzinfo=timezone.utc)
ALPHA: dict[str, Any] = {"name": "alpha", "generation": "aaaa-1", "status": "running",
                         "running": True}
APP = [PublishedApp(**ALPHA)]
HOURS = 3600.0


def status(result: Result = "applied", *, at: datetime = T0, reason: str | None = None,
           **fields: Any) -> AgentStatus:
    attempt = Attempt(time=at.isoformat(), revision=REV, result=result, reason=reason)
    base: dict[str, Any] = {"vehicle": "rav4-07", "follows": "desired-state.yaml",
                            "desired_revision": REV, "applied_revision": REV,
                            "last_attempt": attempt, "passes": [attempt]}
    return AgentStatus(**{**base, **fields})


def published(mark: str, *, at: datetime = T0, result: str = "pushed") -> Publication:
    return Publication.model_validate({"time": at.isoformat(), "fingerprint": mark,
                                       "result": result})


def test_the_times_and_the_list_of_passes_do_not_count() -> None:
    first = status(at=T0)
    later = status("nothing to do", at=T0 + timedelta(minutes=5),
                   passes=[*first.passes, *status(at=T0 + timedelta(minutes=5)).passes])
    assert fingerprint(first, APP) == fingerprint(later, APP)


def test_the_last_publication_does_not_count() -> None:
    plain = status()
    noted = plain.model_copy(update={"publication": published("x")})
    assert fingerprint(plain, APP) == fingerprint(noted, APP)


@pytest.mark.parametrize(("change", "app"), [
    ({"applied_revision": NEW}, APP),
    ({"desired_revision": NEW}, APP),
    ({"follows": "vehicles/rav4-07.yaml"}, APP),
    ({"vehicle": "rav4-01"}, APP),
    ({}, [PublishedApp(**{**ALPHA, "running": False})]),
    ({}, [PublishedApp(**{**ALPHA, "generation": "bbbb-2"})]),
    ({}, [PublishedApp(**{**ALPHA, "status": "installed"})]),
    ({}, []),
])
def test_what_the_fleet_sees_counts(change: dict[str, Any], app: list[PublishedApp]) -> None:
    assert fingerprint(status(**change), app) != fingerprint(status(), APP)


def test_a_failed_pass_and_its_reason_count() -> None:
    failed = status("failed", reason="vehicles/rav4-07.yaml:2:1: unknown key 'aap'")
    other = status("failed", reason="vehicles/rav4-07.yaml:3:1: unknown key 'ap'")
    assert len({fingerprint(s, APP) for s in (status(), failed, other)}) == 3


def test_a_deferral_counts_but_not_its_changing_reason() -> None:
    one = status("deferred", reason="the cutover is deferred: stationary for 12 s")
    two = status("deferred", reason="the cutover is deferred: stationary for 47 s")
    assert fingerprint(one, APP) == fingerprint(two, APP) != fingerprint(status(), APP)


def test_applied_and_nothing_to_do_on_one_revision_are_the_same_news() -> None:
    assert fingerprint(status("applied"), APP) == fingerprint(status("nothing to do"), APP)


def test_the_first_status_is_due() -> None:
    assert due(None, "m", T0, heartbeat=6 * HOURS) == "first"


def test_an_unchanged_status_waits_for_the_heartbeat() -> None:
    last = published("m")
    for minutes in (0, 5, 60, 359):
        assert due(last, "m", T0 + timedelta(minutes=minutes), heartbeat=6 * HOURS) is None
    assert due(last, "m", T0 + timedelta(hours=6), heartbeat=6 * HOURS) == "heartbeat"
    assert due(last, "m", T0 + timedelta(days=3), heartbeat=6 * HOURS) == "heartbeat"


def test_a_changed_status_is_due_at_once() -> None:
    assert due(published("m"), "n", T0 + timedelta(seconds=1), heartbeat=6 * HOURS) == \
        "changed"


def test_a_push_the_network_lost_is_retried_at_the_next_pass() -> None:
    last = published("m", result="failed")
    assert due(last, "m", T0 + timedelta(minutes=5), heartbeat=6 * HOURS) == "retry"


def test_a_repository_that_refused_is_asked_again_only_at_a_change_or_the_heartbeat() -> None:
    last = published("m", result="refused")
    assert due(last, "m", T0 + timedelta(minutes=5), heartbeat=6 * HOURS) is None
    assert due(last, "n", T0 + timedelta(minutes=5), heartbeat=6 * HOURS) == "changed"
    assert due(last, "m", T0 + timedelta(hours=6), heartbeat=6 * HOURS) == "heartbeat"


def test_a_clock_that_went_back_does_not_silence_the_car() -> None:
    last = published("m", at=T0 + timedelta(days=400))  # the Pi booted with a wrong date
    assert due(last, "m", T0, heartbeat=6 * HOURS) == "heartbeat"


def test_times_in_other_zones_compare_as_instants() -> None:
    east = published("m", at=T0.astimezone(timezone(timedelta(hours=2))))
    assert due(east, "m", T0 + timedelta(hours=1), heartbeat=6 * HOURS) is None


def test_a_status_branch_restarts_past_its_bound() -> None:
    assert not keeps_parent(0)  # no branch yet: the first commit has no parent
    assert all(keeps_parent(n) for n in range(1, HISTORY))
    assert not keeps_parent(HISTORY)
    assert not keeps_parent(HISTORY + 5)  # a longer branch (an older lpam's) is cut too


def test_a_long_run_never_holds_more_than_the_bound() -> None:
    length, longest = 0, 0
    for _ in range(10 * HISTORY + 3):
        length = length + 1 if keeps_parent(length) else 1
        longest = max(longest, length)
    assert longest == HISTORY and 1 <= length <= HISTORY
