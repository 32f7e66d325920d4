"""A desired state's places travel with it as a value (issue 29, item 4).

Loading a desired state returns `DesiredDocument`: the model and each app entry's line and
column in its file. Nothing is keyed by the model's identity, so a copy of the model — as
sync's anchoring of relative URLs makes one — or a model made again from its data still
has its two apps that claim one resource refused at the second app's file:line:column.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest

from reconciler.adapters.git import GitStore
from reconciler.adapters.memory import Folder, MemoryStore
from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.core.documents import DesiredDocument, load_desired_document
from reconciler.core.planning.model import Targets
from reconciler.engine.observe.targets import Fetch, resolve
from reconciler.workflow.machine import Machine
from reconciler.workflow.planning import refuse_shared_claims
from reconciler.workflow.source import SOURCE_KEY, anchored, desired_at
from reconciler.workflow.sync import Followed
from schemas.desired import DesiredState

APPS_URL = "https://github.com/owner/apps"
FLEET_URL = "https://github.com/owner/fleet"
COMMIT = "a" * 40
REVISION = "b" * 40

CATALOG = """\
apps:
  - name: ctl-a
    properties:
      - owns_panda: true
  - name: recorder
  - name: ctl-b
    properties:
      - owns_panda: true
"""

SEVERAL = f"""\
version: 2
repositories:
  - url: {{url}}
    ref: {COMMIT}
apps:
  - name: ctl-a
  - recorder
  - name: ctl-b
    params: {{{{MODE: fast}}}}
"""
"""ctl-a at 6:5, recorder at 7:5, ctl-b (which cannot also have the panda) at 8:5."""


def apps_store() -> MemoryStore:
    tree: dict[str, Folder] = {"": ("t0", {"libpanda-apps.yaml": CATALOG})}
    tree.update({name: (f"t-{name}", {"start.sh": "true\n"})
                 for name in ("ctl-a", "recorder", "ctl-b")})
    return MemoryStore(remotes={APPS_URL: {COMMIT: tree}})


def targets_of(desired: DesiredState, store: MemoryStore) -> Targets:
    return resolve(desired, base_dir=Path("."), store=store, fetch=Fetch.CHECKOUT,
                   default_user="root")


def refused_at(document: DesiredDocument) -> ConfigError:
    targets = targets_of(document.desired, apps_store())
    with pytest.raises(ConfigError) as caught:
        refuse_shared_claims(document.path, document.places, targets)
    return caught.value


COPIES: dict[str, Callable[[DesiredState], DesiredState]] = {
    "model_copy": lambda desired: desired.model_copy(),
    "made again": lambda desired: DesiredState.model_validate(desired.model_dump()),
    "anchored": lambda desired: anchored(desired, FLEET_URL),
}


@pytest.mark.parametrize("copy", COPIES.values(), ids=COPIES.keys())
def test_a_copied_desired_state_is_refused_at_its_apps_places(
        tmp_path: Path, copy: Callable[[DesiredState], DesiredState]) -> None:
    path = tmp_path / "desired.yaml"
    path.write_text(SEVERAL.format(url=APPS_URL))
    loaded = load_desired_document(path)
    assert loaded.path == path and loaded.places == ((6, 5), (7, 5), (8, 5))
    copied = replace(loaded, desired=copy(loaded.desired))
    assert copied.desired is not loaded.desired and copied.desired == loaded.desired
    for document in (loaded, copied):
        error = refused_at(document)
        assert error.where == f"{path}:8:5"  # ctl-b, the app that cannot also have it
        assert f"app ctl-b claims the exclusive resource panda, which app ctl-a ({path}:6:5)" \
            f" claims too" in error.message


def test_without_places_the_refusal_names_the_file_alone(tmp_path: Path) -> None:
    """A desired state made in code has no places: the message is the same, unplaced."""
    path = tmp_path / "desired.yaml"
    path.write_text(SEVERAL.format(url=APPS_URL))
    error = refused_at(replace(load_desired_document(path), places=()))
    assert error.where == str(path)
    assert f"which app ctl-a ({path}) claims too" in error.message


def test_a_version_1_app_is_placed_where_the_file_writes_it(tmp_path: Path) -> None:
    path = tmp_path / "desired.yaml"
    path.write_text(f"version: 1\nrepositories:\n  - url: {APPS_URL}\n"
                    "app:\n  name: ctl-a\n")
    document = load_desired_document(path)
    assert [a.name for a in document.desired.apps] == ["ctl-a"]
    assert document.places == ((4, 1),)  # its `app:`, as the file has it


class FleetMachine(Machine):
    """A machine whose repository store is the in-memory twin holding the fleet."""

    twin: MemoryStore

    def store(self) -> GitStore:
        return self.twin  # type: ignore[return-value]


def test_the_fleets_file_keeps_its_places_through_the_anchoring(tmp_path: Path) -> None:
    """Sync reads the fleet's file and makes its relative URLs absolute — a copy of the
    model — and still refuses the conflict at the file's (labelled) line and column."""
    fleet = {"": ("t-fleet", {"desired-state.yaml": SEVERAL.format(url="../apps")})}
    twin = apps_store()
    twin.remotes[FLEET_URL] = {REVISION: fleet}
    twin.fetch(SOURCE_KEY, FLEET_URL)
    machine = FleetMachine(Layout(tmp_path))
    machine.twin = twin

    found = desired_at(machine, FLEET_URL, REVISION, "desired-state.yaml")
    assert found is not None
    assert found.desired.repositories[0].url == APPS_URL  # anchored: a copy of the model
    label = Path(f"fleet@{REVISION[:12]}/desired-state.yaml")
    assert found.path == label
    error = refused_at(found)
    assert error.where == f"{label}:8:5"
    assert f"which app ctl-a ({label}:6:5) claims too" in error.message

    chosen = Followed.of(found, tmp_path)
    assert (chosen.label, chosen.desired, chosen.places) == \
        (label, found.desired, found.places)
