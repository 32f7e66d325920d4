"""`lpam validate` reads every kind of document lpam reads (issue 18, item 6): the kind is
decided from the document's own keys or forced with `--kind`, the output names it, and
every fault — an undecidable kind included — names file:line:column and what to do."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError
from reconciler.core.planning.plan import fingerprint
from reconciler.core.planning.plan import seal as sealed
from reconciler.frontends.cli import VALIDATE_KINDS
from reconciler.workflow.validation import Kind, validate
from schemas.plan import CheckoutStep, Phase
from schemas.record import StateRecord

TOP = Path(__file__).resolve().parents[2]

AGENT = """\
version: 1
source: {url: "https://github.com/our-lab/fleet-state", branch: main}
vehicle: rav4-07
interval_seconds: 300
"""


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def saved_plan(tmp_path: Path, *, offline: bool = False, **changes: object) -> Path:
    """A sealed plan of one checkout step, as `lpam plan -o` writes it (or `lpam plan
    --offline --json`); `changes` edit the JSON afterwards (an edited plan)."""
    step = CheckoutStep(id="checkout:apps", phase=Phase.PREPARE, key="apps",
                        url="git://h/apps.git", ref="main", commit="a" * 40)
    plan = sealed(StateRecord(lineage="l-1", serial=3), [], [step],
                  now=datetime(2024, 1, 1, tzinfo=timezone.utc), lpam_version="0.1.0", summary="")
    if offline:
        plan = plan.model_copy(update={"offline": True})
        plan = plan.model_copy(update={"fingerprint": fingerprint(plan)})
    data = json.loads(plan.model_dump_json())
    data.update(changes)
    return write(tmp_path, "plan.json", json.dumps(data, indent=2) + "\n")


def test_the_readme_agent_yaml_with_a_vehicle_id_is_agent_settings(tmp_path: Path) -> None:
    """The issue's report: `vehicle: rav4-07` was read as a desired state's `vehicle:`."""
    done = validate(write(tmp_path, "agent.yaml", AGENT))
    assert "is agent settings (version 1)" in done
    assert "follows https://github.com/our-lab/fleet-state (branch main) as vehicle rav4-07" \
        in done


@pytest.mark.parametrize(("text", "said"), [
    ("version: 1\nrepositories: []\napp: null\n", "is a desired state (version 1)"),
    # a desired state's `vehicle:` is its CAN signal (a mapping), the agent's an id
    ("version: 1\nvehicle: {stale_seconds: 5}\ngates: {stationary_seconds: 60}\n",
     "is a desired state"),
    ("version: 0.0\nrepositories: {jmscslgroup/libpanda-default-apps: {branch: main}}\n"
     "current: pandarecord\n", "is a desired state (version 0.0), read as version 2"),
    ("apps:\n  - name: logger\n", "is an app catalog with 1 app (logger)"),
    ("version: 1\nsource: {url: 'https://h/fleet'}\nvehicle_file: /etc/libpanda.d/vin\n",
     "as the vehicle named in /etc/libpanda.d/vin"),
    ("version: 1\nsource: {url: 'https://h/fleet'}\n", "as this machine's hostname"),
])
def test_the_kind_is_read_from_the_document(tmp_path: Path, text: str, said: str) -> None:
    assert said in validate(write(tmp_path, "doc.yaml", text))


def test_a_saved_plan_is_recognised_and_read_as_apply_reads_it(tmp_path: Path) -> None:
    done = validate(saved_plan(tmp_path))
    assert "is a saved plan (format 2, lpam 0.1.0" in done
    assert "1 step;" in done and "serial 3" in done


def test_an_app_repository_folder(tmp_path: Path) -> None:
    done = validate(TOP / "examples/example-apps")
    assert "is an app repository with 3 apps" in done


def test_kind_forces_the_reading(tmp_path: Path) -> None:
    """A desired state read as agent settings is refused at its first foreign key."""
    path = write(tmp_path, "d.yaml", "version: 1\nsource: {url: 'https://h/f'}\n"
                 "repositories: []\n")
    with pytest.raises(ConfigError) as info:
        validate(path, Kind.AGENT)
    assert (info.value.line, info.value.column) == (3, 1)
    assert "unknown key 'repositories'" in info.value.message
    with pytest.raises(ConfigError) as info:
        validate(path, Kind.DESIRED)
    assert "unknown key 'source'" in info.value.message and info.value.line == 2
    with pytest.raises(ConfigError) as info:
        validate(path, Kind.REPOSITORY)
    assert "is a file, not an app repository folder" in info.value.message
    with pytest.raises(ConfigError) as info:
        validate(TOP / "examples/example-apps", Kind.CATALOG)
    assert "is a folder, not an app catalog" in info.value.message


def test_a_tie_between_kinds_is_refused_at_its_key_naming_both(tmp_path: Path) -> None:
    path = write(tmp_path, "both.yaml", "# which?\nrepositories: []\napps: []\n")
    with pytest.raises(ConfigError) as info:
        validate(path)
    error = info.value
    assert "a desired state (repositories) and an app catalog (apps)" in error.message
    assert (error.path, error.line, error.column) == (path, 3, 1)
    assert error.hint is not None and "--kind desired-state|catalog|agent|plan" in error.hint


@pytest.mark.parametrize(("text", "found", "line"), [
    ("version: 1\n\nnothing_here: 1\n", "none of its keys (version, nothing_here)", 1),
    ("# comment\n- a\n- b\n", "it holds a list", 1),
    ("just text\n", "it holds a single value", 1),
])
def test_an_unknowable_document_names_the_kinds_it_could_be(
    tmp_path: Path, text: str, found: str, line: int,
) -> None:
    with pytest.raises(ConfigError) as info:
        validate(write(tmp_path, "what.yaml", text))
    error = info.value
    assert found in error.message and error.line == line and error.column == 1
    for kind in ("a desired state", "an app catalog", "agent settings", "a saved plan"):
        assert kind in error.message
    assert error.hint is not None and "--kind" in error.hint


def test_a_guessed_kind_says_so_in_the_hint(tmp_path: Path) -> None:
    """A fault found after guessing says which kind the document was read as: the user
    may have meant another."""
    path = write(tmp_path, "agent.yaml", "version: 1\nsource: {url: 'https://h/f'}\n"
                 "vehicle: rav4-07\nintervall: 60\n")
    with pytest.raises(ConfigError) as info:
        validate(path)
    assert "unknown key 'intervall'" in info.value.message and info.value.line == 4
    assert info.value.hint is not None and "read as agent settings" in info.value.hint


def test_a_broken_plan_is_located_in_its_json(tmp_path: Path) -> None:
    path = saved_plan(tmp_path)
    text = path.read_text().replace('"kind": "checkout"', '"kind": "chekout"')
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        validate(path)
    line = next(n for n, t in enumerate(text.splitlines(), 1) if '"chekout"' in t)
    assert info.value.line == line and info.value.column is not None
    assert "steps.0.kind" in info.value.message


def test_an_edited_or_offline_plan_is_refused_as_apply_refuses_it(tmp_path: Path) -> None:
    edited = saved_plan(tmp_path, serial=4)
    with pytest.raises(ConfigError) as info:
        validate(edited)
    assert "fingerprint does not match" in info.value.message
    assert info.value.line == next(n for n, t in enumerate(edited.read_text().splitlines(), 1)
                                   if '"fingerprint"' in t)
    offline = saved_plan(tmp_path, offline=True)  # `lpam plan --offline --json`
    with pytest.raises(ConfigError) as info:
        validate(offline, Kind.PLAN)
    assert "cannot be applied" in info.value.message


def test_the_cli_offers_every_kind() -> None:
    assert tuple(kind.value for kind in Kind) == VALIDATE_KINDS


def test_an_offline_plan_is_refused_at_its_offline_key_without_the_yaml_reader(
        tmp_path: Path) -> None:
    """`lpam validate` places a plan's fault as `lpam apply PLAN` does, by `json`: the
    plan is never composed as YAML (issue 32 item 2)."""
    from unittest import mock

    from ruamel.yaml.composer import Composer

    offline = saved_plan(tmp_path, offline=True)
    text = offline.read_text()
    at = text.index('"offline"')
    with mock.patch.object(Composer, "get_single_node", side_effect=AssertionError(
            "composed as YAML")), pytest.raises(ConfigError) as info:
        validate(offline, Kind.PLAN)
    assert "cannot be applied" in info.value.message
    assert (info.value.line, info.value.column) == (text.count("\n", 0, at) + 1,
                                                    at - text.rfind("\n", 0, at))
