"""Fuzzing every kind of document lpam reads: only located, bounded LpamErrors may escape.

Documents come from users, from repositories anyone can push to, from an old tool's
folder, and from lpam's own files after a power cut; so for each kind — desired state, app
catalog, LPAM folder, saved plan, state record — hypothesis mutates valid seeds
(structure-aware hazards: tags, anchors, directives, deep nesting, lone surrogates, huge
values, binary garbage, plus random edits of the text) and checks that reading one either
succeeds or fails with an `LpamError`; a `ConfigError` about a YAML document names its
line and column; no message grows past a few hundred characters.

The normal run tries LPAM_FUZZ_EXAMPLES (default 150) documents per kind;
`LPAM_FUZZ_EXAMPLES=10000` is the long run recorded in docs/reliability.md. Every
document that ever broke this is kept in tests/fixtures/fuzz/<kind>/ and replayed by
`test_past_failures_stay_fixed`.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from reconciler.base.errors import ConfigError, LpamError
from reconciler.base.layout import Layout
from reconciler.core.documents import load_desired, load_plan, parse_catalog
from reconciler.engine.records.legacy import import_lpam
from reconciler.engine.records.state import read_record
from tests.lengths import knob

EXAMPLES = knob("LPAM_FUZZ_EXAMPLES", 150, 10000)  # LPAM_LONG=1: 10,000 (tests/lengths.py)
MESSAGE_LIMIT = 600  # the path, line and column come on top of LpamError's 400
ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / "tests" / "fixtures" / "fuzz"
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=EXAMPLES <= 150,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

DESIRED_SEED = """\
version: 1
repositories:
  - repo: jmscslgroup/libpanda-default-apps
    ref: main
  - url: git://127.0.0.1:9418/lab/apps.git
    name: lab
app:
  name: pandarecord
  repository: lab
  params: {RATE_HZ: "10", MODE: fast}
"""
CATALOG_SEED = (ROOT / "tests/fixtures/libpanda-default-apps.libpanda-apps.yaml").read_text()
RECORD_SEED = json.dumps({
    "version": 2, "lineage": "9d4c", "serial": 3,
    "repositories": [{"key": "lab", "url": "git://h/lab.git", "ref": None, "commit": "a" * 40}],
    "app": {"name": "x", "repository": "lab", "commit": "a" * 40, "tree": "b" * 40,
            "path": "x", "params": {"K": "1"}, "generation": "bbbbbbbbbbbb-12345678",
            "status": "running", "run": None},
    "strays": [],
}, indent=2)
PLAN_SEED = json.dumps({
    "format_version": 1, "lpam_version": "0.1.0", "created_at": "2026-11-23T08:00:00+00:00",
    "lineage": None, "serial": 0, "offline": False, "summary": "Plan: 1 to add.",
    "changes": [{"address": "app", "action": "create", "reason": "install x",
                 "before": None, "after": {"name": "x"}, "warnings": []}],
    "steps": [{"id": "install:x@1", "kind": "install", "phase": "cutover",
               "args": {"app": "x", "params": {"K": "1"}}, "needs": []}],
    "fingerprint": "0" * 64,
}, indent=2)
MANIFEST_SEED = "libpanda-default-apps:\n  branch: main\njmscslgroup/cbf: 49f281a\n"
CSV_SEED = "jmscslgroup/libpanda-default-apps, main\nlab/apps, 5f2c1e9\n"

HAZARDS = [
    "!!bool ex", "!!int name", "!!set {a, b}", "!!omap [a: 1]", "!foo x", "&a [*a]", "*a",
    "<<: *base", "%YAML 1.3\n---\n", "%TAG ! tag:x,2000:\n---\n", '"\\ud800"', '"\\udfff x"',
    "[" * 300, "{" * 300, "- " * 200, "x" * 5000, "\t", "\x00", "\ufeff", "---\n", "...\n",
    "? complex\n: key", "|\n  block", ">-\n  folded", "'''", '"', "#", ":", "- - - -",
    "version: 99", "version: 0", "version: '1'", "url: host:path", "url: git://h:99999/x",
    "url: /dev/zero", "name: ../../etc", "BASH_ENV: x", "LD_PRELOAD: x", "PATH: /tmp",
    "\u202e", "\U0001f697", "1e999", "0x1f", "~", "null", "[]", "{}",
]


@st.composite
def mutated(draw: st.DrawFn, seed: str, hazards: list[str] = HAZARDS) -> str:
    """`seed` with a few random edits: hazards inserted, spans deleted or duplicated."""
    text = seed
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(text)))
        edit = draw(st.sampled_from(["hazard", "delete", "duplicate", "chars"]))
        if edit == "hazard":
            text = text[:at] + draw(st.sampled_from(hazards)) + text[at:]
        elif edit == "delete":
            text = text[:at] + text[at + draw(st.integers(1, 40)):]
        elif edit == "duplicate":
            text = text[:at] + text[at:at + draw(st.integers(1, 80))] * 2 + text[at:]
        else:
            text = text[:at] + draw(st.text(max_size=12)) + text[at:]
    return text


def deep(kind: str) -> st.SearchStrategy[str]:
    """A document nested far deeper than any real one, in YAML or JSON."""
    depth = st.integers(50, 20_000)
    if kind == "json":
        return depth.map(lambda n: '{"version": 2, "a": ' + "[" * n + "]" * n + "}")
    return depth.map(lambda n: "version: 1\nrepositories: " + "[" * n + "]" * n + "\n")


def documents(seed: str, kind: str = "yaml") -> st.SearchStrategy[str]:
    return st.one_of(mutated(seed), deep(kind), st.text(max_size=200))


def check(error: LpamError, *, located: bool) -> None:
    """What a user sees of a failure: one bounded message, at a line and column for YAML."""
    assert len(error.message) <= MESSAGE_LIMIT, error.message[:200]
    if isinstance(error, ConfigError) and located:
        assert error.path is not None
        if error.line is not None:
            assert error.line >= 1 and (error.column is None or error.column >= 1)


def attempt(read: Callable[[], object], *, located: bool = True) -> None:
    try:
        read()
    except LpamError as error:
        check(error, located=located)


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    return path


@FUZZ
@given(documents(DESIRED_SEED))
def test_desired_states(text: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        attempt(lambda: load_desired(write(Path(tmp) / "desired.yaml", text)))


@FUZZ
@given(documents(CATALOG_SEED))
def test_catalogs(text: str) -> None:
    attempt(lambda: parse_catalog(Path("lab@aaaa/libpanda-apps.yaml"), text))


@FUZZ
@given(st.fixed_dictionaries({
    "app-manifest.yaml": documents(MANIFEST_SEED),
    "app-manifest.csv": documents(CSV_SEED),
    "app": st.one_of(st.just("pandarecord\n"), st.text(max_size=40)),
    "apps/pandarecord/rosRepositories.csv": documents("jmscslgroup,can_to_ros,main\n"),
}), st.sets(st.sampled_from(["app-manifest.yaml", "app-manifest.csv", "app"])))
def test_lpam_folders(files: dict[str, str], left_out: set[str]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        etc = Path(tmp) / "libpanda.d"
        for name, text in files.items():
            if name not in left_out:
                write(etc / name, text)
        (etc / "apps-repositories" / "jmscslgroup" / "cbf" / ".git").mkdir(parents=True)
        attempt(lambda: import_lpam(etc))


@FUZZ
@given(documents(PLAN_SEED, "json"))
def test_saved_plans(text: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        attempt(lambda: load_plan(write(Path(tmp) / "p.json", text)), located=False)


@FUZZ
@given(documents(RECORD_SEED, "json"))
def test_state_records(text: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        layout = Layout(Path(tmp))
        write(layout.state_record, text)
        attempt(lambda: read_record(layout), located=False)


READERS: dict[str, Callable[[Path], object]] = {
    "desired-state": load_desired,
    "catalog": lambda path: parse_catalog(path, path.read_text("utf-8", "surrogateescape")),
    "plan": load_plan,
}


@pytest.mark.parametrize("case", sorted(p for p in CORPUS.glob("*/*") if p.is_file()),
                         ids=lambda p: f"{p.parent.name}/{p.name}")
def test_past_failures_stay_fixed(case: Path) -> None:
    """Each past crasher is now a located ConfigError (it used to be an internal error)."""
    with pytest.raises(ConfigError) as caught:
        READERS[case.parent.name](case)
    check(caught.value, located=True)
    assert caught.value.path == case
    if case.parent.name != "plan":
        assert caught.value.line is not None and caught.value.column is not None
