"""`lpam status` against a twin of the repository store: what it shows, and what it does
not let a repository do to the answer (fail it, or write escape sequences to a terminal).

The real store and real links are in tests/integration/test_status_safety.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.errors import GitError, StoreDamagedError
from reconciler.base.layout import Layout
from reconciler.engine.records.state import write_record
from reconciler.report import status
from reconciler.report.table import CELL_LIMIT
from schemas.record import AppRecord, AppStatus, RepositoryRecord, StateRecord, Stray

OLD, NEW = "a" * 40, "b" * 40
CATALOG = b"apps:\n  - name: alpha\n  - name: beta\n"


class Blobs:
    """Committed files by (key, commit, path); a path mapped to an exception raises it."""

    def __init__(self, files: dict[tuple[str, str, str], bytes | Exception]) -> None:
        self.files = files
        self.damaged: dict[str, str] = {}  # key → damage: its objects unreadable
        self.lost: set[str] = set()  # damaged keys whose objects seem absent (a lost index)

    def location(self, key: str) -> Path:
        return Path("/nonexistent/lpam-test") / key  # no checkout: no parsed catalog kept

    def has_commit(self, key: str, commit: str) -> bool:
        if key in self.lost:
            return False
        self._readable(key)
        return any(k == key and c == commit for k, c, _ in self.files)

    def damage(self, key: str) -> str | None:
        return self.damaged.get(key)

    def _readable(self, key: str) -> None:
        if key in self.damaged:
            raise StoreDamagedError(key, self.damaged[key])

    def read_file(self, key: str, commit: str, path: str) -> bytes | None:
        self._readable(key)
        found = self.files.get((key, commit, path))
        if isinstance(found, Exception):
            raise found
        return found


def blobs(extra: dict[str, bytes | Exception] | None = None) -> Blobs:
    """A repository `apps` at NEW with alpha and beta, and `extra` files by path."""
    commit = NEW
    files: dict[tuple[str, str, str], bytes | Exception] = {
        ("apps", commit, "libpanda-apps.yaml"): CATALOG,
        ("apps", commit, "alpha/description.txt"): b"the alpha app\n",
        ("apps", commit, "alpha/service"): b"can\n",
        ("apps", commit, "beta/description.txt"): b"the beta app\n",
    }
    files.update({("apps", commit, path): v for path, v in (extra or {}).items()})
    return Blobs(files)


def record(app: str | None = "alpha", state: AppStatus = "running", *,
           commit: str = NEW, strays: list[Stray] | None = None) -> StateRecord:
    installed = None if app is None else AppRecord(
        name=app, repository="apps", commit=commit, tree="t" * 40, path=f"{app}/",
        generation="g1", status=state)
    return StateRecord(
        repositories=[RepositoryRecord(key="apps", url="git://x/apps.git", ref=None,
                                       commit=NEW, applied=NEW)],
        apps=[] if installed is None else [installed], strays=strays or [])


@pytest.fixture
def layout(tmp_path: Path) -> Layout:
    return Layout(tmp_path / "root")


@pytest.mark.parametrize("state", ["installing", "installed", "starting", "running",
                                   "stopping", "uninstalling"])
def test_each_app_shows_its_lifecycle_status(layout: Layout, state: AppStatus) -> None:
    write_record(layout, record(state=state))
    shown = status.as_json(layout, store=blobs())
    apps = {r["app"]: r for r in shown["apps"]}
    assert (apps["alpha"]["status"], apps["alpha"]["installed"]) == (state, True)
    assert apps["alpha"]["running"] is (state == "running")
    assert (apps["beta"]["status"], apps["beta"]["installed"]) == (None, False)
    assert shown["app"]["status"] == state
    header, alpha, beta = status.as_table(layout, store=blobs()).splitlines()
    # the table says the status word (the record's lifecycle is the JSON's `status`) and,
    # for a script under way or cut off, which script
    word = {"installing": "starting", "starting": "starting", "stopping": "stopping",
            "uninstalling": "stopping"}.get(state, "unverified:")
    assert "Status" in header.split() and word in alpha.split() and word not in beta
    script = {"installing": "install.sh", "uninstalling": "uninstall.sh"}.get(state, state)
    assert script in alpha, alpha


def test_a_file_too_large_leaves_the_rest_of_the_answer(layout: Layout) -> None:
    too_big = GitError("apps: 'alpha/service' is 600000000 bytes")
    rows = status.rows(layout, record=record(), store=blobs({"alpha/service": too_big}))
    assert [(r.app, r.service, r.description) for r in rows] == [
        ("alpha", "-", "the alpha app"), ("beta", "-", "the beta app")]
    catalog_too_big = blobs({"libpanda-apps.yaml": GitError("catalog is 600000000 bytes")})
    [note] = status.rows(layout, record=record(app=None), store=catalog_too_big)
    assert note.app == "-" and "600000000 bytes" in note.description


def test_the_table_never_sends_control_characters_to_the_terminal(layout: Layout) -> None:
    write_record(layout, record())
    hostile = blobs({"alpha/service": b"\x1b]0;owned\x07can\rfake\n",
                     "alpha/description.txt": b"\x1b[2J" + b"x" * 10_000 + b"\n"})
    table = status.as_table(layout, store=hostile)
    assert all(c.isprintable() or c == "\n" for c in table)
    assert max(len(cell) for line in table.splitlines() for cell in line.split()) \
        <= CELL_LIMIT
    shown = status.as_json(layout, store=hostile)  # whole, escaped by json.dumps
    assert shown["apps"][0]["service"] == "\x1b]0;owned\x07can\rfake"


def test_the_installed_app_shows_the_files_of_the_commit_it_came_from(
    layout: Layout
) -> None:
    """The repository may have moved on (an apply cut off before the cutover): the files
    shown for the installed app are those of what runs, not of the newer commit."""
    store = blobs()
    store.files.update({("apps", OLD, "alpha/description.txt"): b"the old alpha\n",
                        ("apps", OLD, "alpha/service"): b"old-can\n"})
    rows = status.rows(layout, record=record(commit=OLD), store=store)
    assert [(r.app, r.service, r.description) for r in rows] == [
        ("alpha", "old-can", "the old alpha"), ("beta", "-", "the beta app")]


def test_the_installed_app_is_shown_when_the_catalog_no_longer_lists_it(
    layout: Layout
) -> None:
    store = blobs()
    store.files.update({("apps", OLD, "gamma/description.txt"): b"the gamma app\n",
                        ("apps", OLD, "gamma/service"): b"can\n"})
    rows = status.rows(layout, record=record("gamma", "starting", commit=OLD), store=store)
    assert [(r.app, r.installed, r.status) for r in rows] == [
        ("alpha", False, None), ("beta", False, None), ("gamma", True, "starting")]
    assert (rows[-1].commit, rows[-1].description, rows[-1].service) == (
        OLD[:12], "the gamma app", "can")


def test_an_app_installed_without_a_record_is_shown(layout: Layout) -> None:
    lost = StateRecord(strays=[Stray(name="alpha", generation="g1")])
    write_record(layout, lost)
    assert status.as_json(layout, store=Blobs({}))["strays"] == [
        {"name": "alpha", "generation": "g1", "stopped": False, "pending": None,
         "fate": "replaced", "adopted_as": None}]
    table = status.as_table(layout, store=Blobs({}))
    assert "No app repositories" in table and "without a record: alpha" in table


@pytest.mark.parametrize("lost", [False, True], ids=["unreadable", "objects-gone"])
def test_a_damaged_repository_keeps_its_row_and_the_rest_still_shows(
    layout: Layout, lost: bool,
) -> None:
    """Issue 18, item 10: a broken pack gave an internal error for the whole table."""
    store = blobs()
    store.files[("tools", NEW, "libpanda-apps.yaml")] = b"apps:\n  - name: gamma\n"
    store.damaged["apps"] = "objects/pack/pack-1.pack does not match its checksum"
    if lost:
        store.lost.add("apps")
    tools = RepositoryRecord(key="tools", url="git://x/tools.git", ref=None, commit=NEW)
    both = record()
    write_record(layout, both.model_copy(update={"repositories": [*both.repositories, tools]}))
    shown = status.as_json(layout, store=store)
    assert [(r["repository"], r["app"], r["installed"]) for r in shown["apps"]] == [
        ("apps", "-", False), ("tools", "gamma", False), ("apps", "alpha", True)]
    assert shown["apps"][0]["damage"] == store.damaged["apps"]
    assert "next `lpam apply` fetches it anew" in shown["apps"][0]["description"]
    table = status.as_table(layout, store=store)
    assert "Repository apps: its copy in the store is damaged: objects/pack/pack-1.pack " \
        "does not match its checksum; the next `lpam apply` moves it aside and fetches " \
        "it anew." in table.splitlines()
