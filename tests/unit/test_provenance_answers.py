"""`lpam provenance`'s answers (workflow/provenance.py) from a timeline written through the
real files: what ran, and the answers that are not "this ran" — before the timeline, a
file of another car, a file with no times, a desired state that cannot be one software."""

from __future__ import annotations

import os
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.core.documents import load_desired
from reconciler.engine.records.timeline import Timeline
from reconciler.workflow import provenance as prov
from schemas.timeline import Edge, Software, Stamp, params_digest

T0 = datetime(2026, 3, 14, 10, tzinfo=timezone.utc)
VIN = "2T3Y1RFV8KC014025"


def at(seconds: float) -> Stamp:
    return Stamp(boot="b1", mono=seconds, wall=T0 + timedelta(seconds=seconds))


def software(params: dict[str, str]) -> Software:
    return Software(app="ctl", generation="g1", repository="apps", commit="c" * 40,
                    path="ctl", tree="t" * 40, url="https://example.org/apps.git",
                    params=params, params_digest=params_digest(params), lpam="0.1.0",
                    vehicle=VIN)


@pytest.fixture
def car(tmp_path: Path) -> prov.Known:
    """ctl with GAIN 1 from 0 s to 100 s, then with GAIN 2 (same generation) from 100 s."""
    timeline = Timeline(Layout(tmp_path))
    one, two = timeline.keep(software({"GAIN": "1"})), timeline.keep(software({"GAIN": "2"}))
    for edge in (Edge(kind="began", how="apply", at=at(0), app="ctl", generation="g1",
                      software=one),
                 Edge(kind="ended", how="apply", at=at(100), app="ctl", generation="g1",
                      software=one),
                 Edge(kind="began", how="apply", at=at(100.1), app="ctl", generation="g1",
                      software=two)):
        timeline.append(edge)
    return prov.known(timeline)


def csv(path: Path, *seconds: float) -> Path:
    rows = "".join(f"{(T0 + timedelta(seconds=s)).timestamp():.6f},0,384,00,1\n"
                   for s in seconds)
    path.write_text("Time,Bus,MessageID,Message,MessageLength\n" + rows)
    return path


def test_a_file_within_one_software_gives_a_desired_state_that_pins_it(
        car: prov.Known, tmp_path: Path) -> None:
    answer = prov.of_file(csv(tmp_path / f"d_{VIN}_CAN_Messages.csv", 10, 50), car)
    assert answer.verdict == "ran"
    text, _ = prov.desired_for(answer.found, car)
    desired = load_desired(_written(tmp_path / "again.yaml", text))
    [repo] = desired.repositories
    assert (repo.url, repo.ref) == ("https://example.org/apps.git", "c" * 40)
    assert [(a.name, a.params) for a in desired.apps] == [("ctl", {"GAIN": "1"})]


def test_a_file_across_a_change_of_parameters_is_not_one_software(
        car: prov.Known, tmp_path: Path) -> None:
    answer = prov.of_file(csv(tmp_path / "d.csv", 50, 150), car)
    assert {car.software[i.software or ""].params["GAIN"] for i in answer.found} == {"1", "2"}
    with pytest.raises(ValueError, match="ran two ways \\(parameters"):
        prov.desired_for(answer.found, car)


def test_what_cannot_be_answered_is_said(car: prov.Known, tmp_path: Path) -> None:
    before = prov.of_file(csv(tmp_path / "old.csv", -9000, -8000), car)
    assert before.verdict == "before lpam" and not before.found
    other = prov.of_file(csv(tmp_path / "d_JTMW1RFV0KD000001_CAN_Messages.csv", 10), car)
    assert other.verdict == "other vehicle" and VIN in other.said
    (tmp_path / "notes.bin").write_bytes(b"\x00\x01")
    os.utime(tmp_path / "notes.bin", (0, 0))  # its only time: 1970
    assert prov.of_file(tmp_path / "notes.bin", car).verdict == "before lpam"
    with pytest.raises(ConfigError, match="no such file"):
        prov.of_file(tmp_path / "missing.bin", car)


def _written(path: Path, text: str) -> Path:
    path.write_text(text)
    return path
