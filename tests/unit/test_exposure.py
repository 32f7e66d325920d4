"""Which of lpam's files another user may change (reconciler/report/exposure.py): the pure
decision from modes and owners, and `lpam status` on real files in a temporary root.

The real CLI after a real apply is in tests/integration/test_file_modes.py.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from reconciler.base.layout import Layout
from reconciler.report import status
from reconciler.report.exposure import ABOVE, Files, Found, exposed, watched
from schemas.record import AppRecord, RepositoryRecord, StateRecord

ME, OTHER = 0, 1000
GENERATION = "0123456789ab-01234567"


def files(*found: Found, user: int = ME) -> Files:
    return Files(found=found, user=user, users={0: "root", 1000: "pi", 1001: None},
                 groups={0: "root", 4: "adm"})


def file(path: str, mode: int, *, what: str | None = "the desired state", uid: int = ME,
         gid: int = 0) -> Found:
    kind = stat.S_IFDIR if what is None or path.endswith("/") else stat.S_IFREG
    return Found(Path(path.rstrip("/")), what, kind | mode, uid, gid)


def test_what_only_its_owner_may_write_is_not_named() -> None:
    assert exposed(files(file("/etc/lpam/desired-state.yaml", 0o644),
                         file("/var/lib/lpam/", 0o755, what="lpam's state"),
                         file("/etc/", 0o755, what=None),
                         file("/var/lib/lpam/state.json", 0o600, what="the state record",
                              uid=OTHER), user=OTHER)) == []


def test_a_group_writable_file_is_named_with_its_group_and_the_fix() -> None:
    [found] = exposed(files(file("/etc/lpam/desired-state.yaml", 0o664, gid=4)))
    assert found.path == "/etc/lpam/desired-state.yaml" and found.writable_by == ["group"]
    assert found.fix == "chmod go-w /etc/lpam/desired-state.yaml"
    assert found.said == (
        "/etc/lpam/desired-state.yaml (the desired state) is writable by its group (adm): "
        "another user can change what lpam runs as root; "
        "`chmod go-w /etc/lpam/desired-state.yaml` closes it")


def test_a_world_writable_directory_above_lpams_files_is_named() -> None:
    [found] = exposed(files(file("/var/", 0o777, what=None)))
    assert (found.what, found.writable_by) == (ABOVE, ["group", "others"])
    assert "is world-writable" in found.said


def test_a_sticky_directory_above_is_safe_but_not_one_of_lpams_own() -> None:
    """Only an entry's owner may move it in a sticky directory (as in /tmp); in lpam's own,
    another user could still add a file lpam reads (an override)."""
    assert exposed(files(file("/var/", 0o1777, what=None))) == []
    [found] = exposed(files(file("/var/lib/lpam/", 0o1777, what="lpam's state")))
    assert found.writable_by == ["group", "others"]


@pytest.mark.parametrize(("uid", "user", "owner"), [
    (1000, 0, "pi (uid 1000)"), (1001, 0, "an unknown user (uid 1001)"),
])
def test_a_path_another_user_owns_is_named_with_the_chown_that_closes_it(
    uid: int, user: int, owner: str
) -> None:
    [found] = exposed(files(file("/var/lib/lpam/repositories/", 0o755,
                                 what="the repository store", uid=uid), user=user))
    assert found.owner == owner and found.writable_by == []
    assert found.fix == "chown root /var/lib/lpam/repositories"
    assert f"is owned by {owner}:" in found.said


def test_owned_by_root_is_never_another_users_and_both_faults_have_one_fix() -> None:
    """Root owns everything already: a file of root's is not exposed to the user lpam runs
    as in a demo root. A path owned by another and writable by others needs both."""
    assert exposed(files(file("/etc/lpam/agent.yaml", 0o644, uid=0), user=OTHER)) == []
    [found] = exposed(files(file("/x y/desired-state.yaml", 0o666, uid=1001), user=OTHER))
    assert found.fix == "chown pi '/x y/desired-state.yaml' && chmod go-w '/x y/desired-state.yaml'"
    assert "world-writable and owned by an unknown user (uid 1001)" in found.said
    assert "what lpam runs as pi" in found.said
    [nameless] = exposed(files(file("/etc/lpam/agent.yaml", 0o644, uid=OTHER), user=1001))
    assert nameless.fix == "chown 1001 /etc/lpam/agent.yaml"  # a command chown takes
    assert "what lpam runs as uid 1001" in nameless.said


def test_watched_is_known_paths_and_the_directories_above_them_to_the_root(
    tmp_path: Path
) -> None:
    layout = Layout(tmp_path / "root")
    record = StateRecord(
        repositories=[RepositoryRecord(key="o/apps", url="u", ref=None, commit="a" * 40)],
        apps=[AppRecord(name="alpha", repository="o/apps", commit="a" * 40, tree="t" * 40,
                        path="alpha/", generation=GENERATION, status="running")])
    paths = [w.path for w in watched(layout, record)]
    whats = {w.path: w.what for w in watched(layout, record)}
    assert len(paths) == len(set(paths)) and paths[0] == layout.root
    assert all(p == layout.root or layout.root in p.parents for p in paths)  # never above
    for path in paths:  # each directory above before what is in it
        assert all(paths.index(p) < paths.index(path) for p in path.parents if p in whats)
    assert whats[layout.root / "var"] is None and whats[layout.var] == "lpam's state"
    assert whats[layout.generation_dir("alpha", GENERATION)] == "the generation alpha runs from"
    assert whats[layout.repository_dir("o/apps")] == "the checkout of o/apps"
    assert whats[layout.desired_state] == "the desired state"


def test_status_of_a_root_names_what_others_may_write_and_nothing_once_closed(
    tmp_path: Path
) -> None:
    """gather's stats on real files, through the one report to the table and the JSON."""
    layout = Layout(tmp_path / "root")
    layout.state_record.parent.mkdir(parents=True, mode=0o755)
    layout.desired_state.parent.mkdir(parents=True, mode=0o755)
    layout.desired_state.write_text("version: 1\n")
    layout.desired_state.chmod(0o644)
    clean = status.as_table(layout, store=None)
    assert "Unsafe" not in clean and status.as_json(layout)["exposed"] == []
    layout.state_record.parent.chmod(0o775)
    [line] = [x for x in status.as_table(layout).splitlines() if x.startswith("Unsafe")]
    assert line.startswith(f"Unsafe: {layout.var} (lpam's state) is writable by its group")
    [found] = status.as_json(layout)["exposed"]
    assert found["fix"] == f"chmod go-w {layout.var}"
    os.chmod(layout.var, 0o755)
    assert status.as_table(layout) == clean
