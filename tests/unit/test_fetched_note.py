"""The one line that tells a user on a metered link what resolving fetched."""

from __future__ import annotations

from reconciler.core.planning.model import RepoTarget, Targets
from reconciler.engine.observe.targets import fetched_note


def repo(key: str, fetched: int | None, alone: bool = True) -> RepoTarget:
    return RepoTarget(key=key, url=f"https://user:secret@example.org/{key}.git", ref=None,
                      commit="a" * 40, fetched=fetched, fetched_alone=alone)


def test_one_repository_is_named_with_its_url_hidden_credentials_and_size() -> None:
    said = fetched_note(Targets((repo("a", 61_300), repo("b", None))))
    assert said is not None and said.startswith("fetched a from https://")
    assert "secret" not in said and said.endswith(": 61.3 kB (the commit alone)")


def test_several_are_summed_and_history_is_said() -> None:
    assert fetched_note(Targets((repo("a", 2_000_000), repo("b", 1_700_000, alone=False)))) \
        == "fetched 2 repositories: 3.7 MB in all (some with their history)"
    assert fetched_note(Targets((repo("a", 300), repo("b", 400)))) == \
        "fetched 2 repositories: 700 bytes in all (each commit alone)"


def test_nothing_fetched_says_nothing() -> None:
    assert fetched_note(Targets((repo("a", None),))) is None
