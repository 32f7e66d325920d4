"""Issue 34's fleet simulation with a few cars (bench/fleetsim.py runs it with 100): real
agent passes of every car against one loopback `git daemon` behind a counting relay, a
revision in waves, a health rollback in wave 2, and the lab's revert."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

from bench.fleetsim import PROVE, simulate


def test_a_rollback_in_wave_two_keeps_the_revision_from_the_rest_and_a_revert_reaches_all(
        tmp_path: Path, hermetic_env: Path) -> None:
    done = simulate(5, tmp_path, home=hermetic_env)
    canary, second, rest = done.waves[0][0], done.waves[1], \
        [n for n in done.cars if n not in done.waves[0] + done.waves[1]]
    r2, r3 = done.revisions["R2"], done.revisions["R3"]
    took = {n: c.applied[r2] for n, c in done.cars.items() if r2 in c.applied}
    assert set(took) == {canary, *(n for n in second if n != done.broken)}
    for name in second:  # wave 2 only after the canary proved R2
        if name in took:
            assert took[name] - took[canary] >= timedelta(seconds=PROVE)
    stages = done.phases[1].stages  # as the waves' phase left them
    broken = stages[done.broken]
    assert broken is not None and (broken["revision"], broken["stage"]) == (r2, "rolled back")
    assert rest
    for name in rest:
        stage = stages[name]
        assert stage is not None and (stage["revision"], stage["stage"]) == (r2, "halted")
        assert f"{done.broken} (wave 2) rolled back" in stage["reason"]
    revert = done.phases[-1]
    assert revert.rounds == 1  # no wave holds a revert
    assert all(c.status()["applied_revision"] == r3 for c in done.cars.values())
    # what the server saw: at most a fetch, a second fetch of the statuses a car waits
    # on (the first time only), an app fetch and a push per pass
    waves = done.phases[1]
    assert waves.traffic.connections <= 3 * waves.passes
    assert revert.traffic.connections <= 2 * revert.passes  # a fetch and a push each
