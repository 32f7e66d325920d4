"""A fetch-only pass (the one at shutdown) records what it really brought: commits it could
not fetch are not "fetched", or the next start would trust an offline apply that cannot be."""

from __future__ import annotations

from typing import Any

import pytest

from reconciler.base.errors import CatalogError, GitError
from reconciler.workflow import sync
from reconciler.workflow.events import Event
from schemas.agent import AgentConfig

REVISION = "c" * 40


def pins(monkeypatch: pytest.MonkeyPatch, error: Exception | None) -> sync.Synced:
    def desired(*args: Any, **kwargs: Any) -> Any:
        if error is not None:
            raise error
        return sync.Followed(label=None, desired=None, base_dir=None)  # type: ignore[arg-type]

    monkeypatch.setattr(sync, "_desired", desired)
    monkeypatch.setattr("reconciler.workflow.planning.plan", lambda *a, **k: None)
    config = AgentConfig.model_validate({"version": 1, "source": {"url": "git://h/fleet"}})
    events: list[Event] = []
    return sync._fetch_pins(None, config, "rav4-07", REVISION,  # type: ignore[arg-type]
                            events.append)


def test_pins_fetched_are_fetched(monkeypatch: pytest.MonkeyPatch) -> None:
    assert pins(monkeypatch, None) == sync.Synced("fetched", REVISION)


def test_pins_git_could_not_reach_are_offline(monkeypatch: pytest.MonkeyPatch) -> None:
    done = pins(monkeypatch, GitError("cannot reach git://h/apps"))
    assert (done.result, done.revision) == ("offline", REVISION)
    assert done.reason is not None and "cannot reach git://h/apps" in done.reason
    assert not done.failed  # the revision is not at fault: the next pass tries it again


def test_pins_of_a_faulty_desired_state_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    done = pins(monkeypatch, CatalogError("app beta is in no catalog"))
    assert (done.result, done.revision) == ("failed", REVISION)
    assert done.reason is not None and "app beta is in no catalog" in done.reason
