"""Exclusive resources (issue 22, item 2): what a catalog app claims, and two desired apps
claiming one resource refused with both apps' positions before anything changes."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reconciler.adapters.memory import MemoryStore
from reconciler.base.errors import ConfigError
from reconciler.base.loading import load
from reconciler.core.documents import parse_catalog
from reconciler.core.planning.resources import Claim, Where, conflicts, owners, refuse
from reconciler.engine.observe.targets import Fetch, resolve
from schemas.desired import DesiredState

REAL_CATALOG = Path("/work/shared/reference/libpanda-default-apps.libpanda-apps.yaml")
URL = "https://github.com/owner/apps"
COMMIT = "a" * 40

FIELD_SHAPE = """\
apps:
  - name: gps2vsl
    properties:
      - owns_panda: true
  - name: tracker
    resources: [gps-serial]
  - name: recorder
"""


def catalog_resources(text: str) -> dict[str, set[str]]:
    catalog = parse_catalog(Path("libpanda-apps.yaml"), text)
    return {app.name: set(app.resources) for app in catalog.apps}


def test_owns_panda_in_either_shape_claims_panda() -> None:
    assert catalog_resources(FIELD_SHAPE) == {
        "gps2vsl": {"panda"}, "tracker": {"gps-serial"}, "recorder": set()}
    paper = "apps:\n  - name: ctl\n    properties:\n      owns_panda: true\n" \
        "      resources: [gps-serial]\n"
    assert catalog_resources(paper) == {"ctl": {"panda", "gps-serial"}}


def test_resources_and_owns_panda_add_up_once() -> None:
    text = "apps:\n  - name: ctl\n    properties:\n      - owns_panda: true\n" \
        "    resources: [panda, gps-serial, panda]\n"
    assert catalog_resources(text) == {"ctl": {"panda", "gps-serial"}}


@pytest.mark.parametrize("bad", ["Panda", "gps_serial", "-x", "service:can", "a b", ""])
def test_a_bad_resource_name_is_refused_at_its_line_and_column(bad: str) -> None:
    text = f"apps:\n  - name: ctl\n    resources:\n      - panda\n      - '{bad}'\n"
    with pytest.raises(ConfigError) as caught:
        parse_catalog(Path("libpanda-apps.yaml"), text)
    assert (caught.value.line, caught.value.column) == (5, 9)
    assert "lower-case letters, digits and '-'" in caught.value.message


def resolved(catalog: str, folders: dict[str, dict[str, str]], app: str) -> frozenset[str]:
    """The desired app's claims as resolving the desired state finds them."""
    tree = {"": ("t0", {"libpanda-apps.yaml": catalog})}
    tree.update({name: (f"t-{name}", files) for name, files in folders.items()})
    store = MemoryStore(remotes={URL: {COMMIT: tree}})
    desired = DesiredState.model_validate(
        {"version": 2, "repositories": [{"url": URL, "ref": COMMIT}], "apps": [{"name": app}]})
    targets = resolve(desired, base_dir=Path("."), store=store, fetch=Fetch.CHECKOUT,
                      default_user="root")
    assert [a.name for a in targets.apps] == [app]
    return targets.apps[0].resources


def test_the_unit_a_service_file_names_is_a_resource() -> None:
    folders = {"gps2vsl": {"service": "can\n"}, "recorder": {"start.sh": "true\n"}}
    assert resolved(FIELD_SHAPE, folders, "gps2vsl") == {"panda", "service:can"}
    assert resolved(FIELD_SHAPE, folders, "recorder") == frozenset()


def test_a_scriptless_apps_own_unit_is_no_resource() -> None:
    """lpam writes it as lpam-app-NAME: no other app shares it (a stray `service` file in
    its folder names nothing lpam runs)."""
    catalog = "apps:\n  - name: speedlog\n    command: [python3, log.py]\n"
    assert resolved(catalog, {"speedlog": {"service": "can\n"}}, "speedlog") == frozenset()


DESIRED = """\
apps:
  - name: gps2vsl
  - name: tracker
  - name: mvt
  - name: recorder
"""


def claims_of(claimed: dict[str, set[str]]) -> list[Claim]:
    """Claims located in a desired state listing the apps in DESIRED's order."""
    doc = load(Path("desired.yaml"), DESIRED)
    found = []
    for index, item in enumerate(doc.data["apps"]):
        if item["name"] in claimed:
            line, column = doc.position(["apps", index])
            found.append(Claim(item["name"], Where(doc.path, line, column),
                               frozenset(claimed[item["name"]])))
    return found


def test_two_apps_claiming_panda_are_refused_naming_both_positions() -> None:
    claims = claims_of({"gps2vsl": {"panda", "service:can"}, "tracker": {"gps-serial"},
                        "mvt": {"panda"}})
    (conflict,) = conflicts(claims)
    assert (conflict.resource, conflict.apps) == ("panda", ("gps2vsl", "mvt"))
    with pytest.raises(ConfigError) as caught:
        refuse(conflicts(claims))
    error = caught.value
    assert error.where == "desired.yaml:4:5"  # mvt, the app that cannot also have it
    assert "app mvt claims the exclusive resource panda" in error.message
    assert "which app gps2vsl (desired.yaml:2:5) claims too" in error.message
    assert error.hint is not None and "keep one of these apps" in error.hint
    with pytest.raises(ConfigError):
        owners(claims)


def test_three_claimants_are_all_named_and_further_conflicts_counted() -> None:
    claims = claims_of({"gps2vsl": {"panda", "service:can"}, "mvt": {"panda"},
                        "recorder": {"panda", "service:can"}})
    found = conflicts(claims)
    assert [(c.resource, c.apps) for c in found] == [
        ("panda", ("gps2vsl", "mvt", "recorder")), ("service:can", ("gps2vsl", "recorder"))]
    with pytest.raises(ConfigError) as caught:
        refuse(found)
    message = caught.value.message
    assert caught.value.where == "desired.yaml:4:5"
    assert "which apps gps2vsl (desired.yaml:2:5) and recorder (desired.yaml:5:5) claim " \
        "too" in message
    assert "1 more resource(s) are claimed twice: service:can" in message


def test_one_unit_named_by_two_apps_says_so() -> None:
    claims = claims_of({"gps2vsl": {"service:can"}, "recorder": {"service:can"}})
    with pytest.raises(ConfigError) as caught:
        refuse(conflicts(claims))
    assert "service:can (each names the unit can in its `service` file)" in \
        caught.value.message
    assert caught.value.where == "desired.yaml:5:5"


def test_apps_that_share_nothing_run_side_by_side() -> None:
    claims = claims_of({"gps2vsl": {"panda", "service:can"}, "tracker": {"gps-serial"},
                        "recorder": set()})
    assert conflicts(claims) == []
    refuse([])
    assert owners(claims) == {"gps-serial": "tracker", "panda": "gps2vsl",
                              "service:can": "gps2vsl"}


def test_an_app_is_not_its_own_rival() -> None:
    here = Where(Path("desired.yaml"), 2, 5)
    twice = [Claim("gps2vsl", here, frozenset({"panda"}))] * 2
    assert conflicts(twice) == [] and owners(twice) == {"panda": "gps2vsl"}


RESOURCES = st.sampled_from(["panda", "gps-serial", "service:can", "service:gps", "lidar"])


@settings(deadline=None)  # no time limit per example: a busy machine (a parallel run) is slow
@given(st.dictionaries(st.sampled_from(["a", "b", "c", "d", "e"]),
                       st.frozensets(RESOURCES, max_size=3), max_size=5))
def test_conflicts_are_exactly_the_resources_with_two_claimants(
    claimed: dict[str, frozenset[str]],
) -> None:
    claims = [Claim(app, Where(Path("d.yaml"), i + 1, 5), res)
              for i, (app, res) in enumerate(claimed.items())]
    claimants = {r: [a for a, res in claimed.items() if r in res]
                 for res in claimed.values() for r in res}
    found = conflicts(claims)
    assert (found == []) == all(len(apps) <= 1 for apps in claimants.values())
    assert {c.resource: list(c.apps) for c in found} == \
        {r: apps for r, apps in claimants.items() if len(apps) > 1}
    assert [c.resource for c in found] == sorted(c.resource for c in found)
    if found:
        with pytest.raises(ConfigError):
            owners(claims)
    else:
        assert owners(claims) == {r: apps[0] for r, apps in claimants.items()}


@pytest.mark.skipif(not REAL_CATALOG.exists(), reason="the field's catalog is not here")
def test_the_field_catalogs_panda_owners() -> None:
    """libpanda-default-apps as the cars have it: these apps say `owns_panda: true`."""
    claims = catalog_resources(REAL_CATALOG.read_text(encoding="utf-8"))
    assert claims == {name: {"panda"} for name in
                      ("cbf", "joy_to_veh", "joystick2toyota", "mvt", "pandarecord")}
