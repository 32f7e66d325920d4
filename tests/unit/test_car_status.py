"""The status a car publishes on `status/<vehicle>` is a typed, versioned document, written
and read in one module (reconciler/core/publication.py): what a car writes reads back, and what
cars of older lpam versions published (no `version`, an agent status version 1) is still
read; what cannot be read is said, never half-understood."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest

import migrations
from migrations import car_status_v0_to_v1, car_status_v2_to_v3
from reconciler.base.errors import ConfigError, VersionError
from reconciler.base.loading import load
from reconciler.core.publication import fingerprint, last_change, read_status_file, status_file
from schemas.agent import AgentStatus, Attempt
from schemas.fleet import CarStatus, PublishedApp
from schemas.override import LocalOverride
from schemas.record import Actor, HistoryEntry

FIXTURES = Path(migrations.__file__).parent / "fixtures" / "car-status" / "v0_to_v1"
WHERE = Path("status/rav4-07/status.json")
STATUS = AgentStatus(vehicle="rav4-07", follows="desired-state.yaml", applied_revision="c" * 40,
                     last_attempt=Attempt(time="2026-11-20T10:00:00+00:00", revision="c" * 40,
                                          result="applied"))
APP = PublishedApp(name="alpha", generation="0123456789ab", status="installed", running=True)


def test_what_a_car_publishes_reads_back() -> None:
    content = status_file(STATUS, [APP])
    body = json.loads(content)
    assert body["version"] == 3 and set(body["app"]) == {"name", "generation", "status",
                                                          "running"}
    assert body["agent"] == STATUS.model_dump(mode="json")  # the agent's part as before
    read = read_status_file(content, where=WHERE)
    assert read is not None and read.agent == STATUS and read.app is not None
    assert (read.app.name, read.app.running) == ("alpha", True)
    assert read_status_file(status_file(STATUS, []), where=WHERE) == CarStatus(agent=STATUS)


def test_a_local_override_is_published_and_read_back() -> None:
    local = LocalOverride(since="2026-11-25T09:00:00+00:00", by="phone", edits=2,
                          revision="c" * 40, seeded=True)
    read = read_status_file(status_file(STATUS, [APP], local), where=WHERE)
    assert read is not None and read.override == local
    assert fingerprint(STATUS, [APP], local) != fingerprint(STATUS, [APP])  # a change is news


def entry(app: str, time: str, apply: int, by: Actor | None) -> HistoryEntry:
    return HistoryEntry(generation=f"{app}-gen", app=app, repository="lab/apps",
                        commit="c" * 40, path=app, tree="t" * 40, time=time,
                        result="applied", apply=apply, by=by)


def test_the_last_change_and_who_made_it_are_published_and_read_back() -> None:
    """Issue 31: the fleet sees who put the car's apps in place — the newest set of its
    history, with the phone (or user, or agent) that asked for it."""
    pixel = Actor(kind="phone", id="AA:BB:CC:DD:EE:01", name="Pixel 7")
    history = [entry("alpha", "2026-11-26T10:00:00+00:00", 4, Actor(kind="agent", id="c" * 40)),
               entry("alpha", "2026-11-27T09:00:00+00:00", 7, pixel),
               entry("rec", "2026-11-27T09:00:00+00:00", 7, pixel)]
    change = last_change(history)
    assert change is not None
    body = json.loads(status_file(STATUS, [APP], None, change))
    assert body["last_change"] == {
        "time": "2026-11-27T09:00:00+00:00", "result": "applied",
        "apps": ["alpha@alpha-gen", "rec@rec-gen"],
        "by": {"kind": "phone", "id": "AA:BB:CC:DD:EE:01", "name": "Pixel 7"}}
    read = read_status_file(status_file(STATUS, [APP], None, change), where=WHERE)
    assert read is not None and read.last_change == change
    assert fingerprint(STATUS, [APP], None, change) != \
        fingerprint(STATUS, [APP], None, last_change(history[:1]))  # who changed is news
    assert last_change([]) is None
    assert fingerprint(STATUS, [APP], None, None) == fingerprint(STATUS, [APP])


@pytest.mark.parametrize("before", sorted((FIXTURES.parent / "v2_to_v3").glob("*.before.yaml")),
                         ids=lambda p: p.name)
def test_car_status_v2_to_v3_names_no_one_and_validates(before: Path) -> None:
    """A version-2 file named no one: `last_change` is null, nothing guessed."""
    data = load(before).data
    original = copy.deepcopy(data)
    after = before.with_name(before.name.replace(".before.", ".after."))
    assert car_status_v2_to_v3.upgrade(data) == load(after).data
    assert data == original, "a step must not modify its input"
    read = CarStatus.model_validate(migrations.upgrade("car-status", data, path=before))
    assert read.last_change is None and read.version == 3


def test_a_version_1_file_has_no_override() -> None:
    body = json.loads(status_file(STATUS, [APP]))
    body["version"] = 1
    del body["override"]
    read = read_status_file(json.dumps(body).encode(), where=WHERE)
    assert read is not None and read.override is None and read.agent == STATUS


def test_a_file_from_before_the_version_is_read() -> None:
    old = {"agent": {**STATUS.model_dump(mode="json"), "version": 1, "follows": None,
                     "publication": None},
           "app": APP.model_dump()}
    del old["agent"]["follows"], old["agent"]["publication"]
    read = read_status_file(json.dumps(old).encode(), where=WHERE)
    assert read is not None and read.agent.applied_revision == "c" * 40
    assert read.agent.follows is None and read.app is not None and read.app.name == "alpha"


def test_no_json_is_nothing_to_show() -> None:
    assert read_status_file(b"\x00garbage", where=WHERE) is None


@pytest.mark.parametrize(("body", "said"), [
    ({"version": 1, "agent": {"version": 2}, "app": {"name": 7}}, "invalid car's status at "
     "app.name"),
    ({"app": None}, "`agent` must be the agent's status"),
])
def test_a_damaged_status_says_where(body: dict[str, Any], said: str) -> None:
    with pytest.raises(ConfigError, match=said) as info:
        read_status_file(json.dumps(body).encode(), where=WHERE)
    assert info.value.path == WHERE


def test_a_newer_lpams_status_says_so() -> None:
    with pytest.raises(VersionError, match="newer lpam"):
        read_status_file(json.dumps({"version": 4, "agent": {}}).encode(), where=WHERE)


def pairs() -> list[tuple[Path, Path]]:
    return [(b, b.with_name(b.name.replace(".before.", ".after.")))
            for b in sorted(FIXTURES.glob("*.before.yaml"))]


@pytest.mark.parametrize(("before", "after"), pairs(), ids=lambda p: p.name)
def test_car_status_v0_to_v1_matches_fixture_and_validates(before: Path, after: Path) -> None:
    data = load(before).data
    original = copy.deepcopy(data)
    assert car_status_v0_to_v1.upgrade(data) == load(after).data
    assert data == original, "a step must not modify its input"
    CarStatus.model_validate(migrations.upgrade("car-status", data, path=before))


def test_fleet_status_shows_each_cars_file_as_read_here(monkeypatch: pytest.MonkeyPatch) -> None:
    """The first branch of a car with a status in JSON counts; a damaged one shows the car
    and why; a file that is no JSON shows nothing (workflow/fleet.py)."""
    from reconciler.adapters import clone
    from reconciler.workflow import fleet

    newer = json.dumps({"version": 9, "agent": {}}).encode()
    files = [clone.Published("rav4-01", b"no json", 1_700_000_000),
             clone.Published("rav4-01", status_file(STATUS, [APP]), 1_700_000_000),
             clone.Published("rav4-07", status_file(STATUS, []), 1_700_000_100),
             clone.Published("rav4-07", newer, 1_700_000_200),
             clone.Published("rav4-09", newer, 1_700_000_300)]
    monkeypatch.setattr(clone, "published", lambda *a, **k: ("c" * 40, files))
    tip, rows = fleet.read(Path("clone"))
    by = {row.vehicle: row for row in rows}
    assert tip == "c" * 40 and set(by) == {"rav4-01", "rav4-07", "rav4-09"}
    assert (by["rav4-01"].app, by["rav4-01"].running, by["rav4-01"].up_to_date) == \
        ("alpha", True, True)
    assert (by["rav4-07"].app, by["rav4-07"].last_pass) == (None, "applied")
    assert by["rav4-09"].applied is None and by["rav4-09"].reason is not None
    assert "newer lpam" in by["rav4-09"].reason
