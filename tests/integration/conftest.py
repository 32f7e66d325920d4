"""Fixtures of the CLI tests: an lpam confined to the test's root and the app repository
of apps.py; and of the fleet tests (sync, agent): a fleet's desired-state repository and
the app repository beside it, served by the test's git daemon, and a car that follows it."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo


@pytest.fixture
def lpam(tmp_path: Path) -> Lpam:
    return Lpam(tmp_path / "root")


@pytest.fixture
def repo(make_repo: Callable[[str], RepoBuilder]) -> RepoBuilder:
    """apps.git with the apps alpha and beta (apps.py)."""
    builder = make_repo("apps.git")
    apps_repo(builder)
    return builder


def fleet_state(app: str, pin: str | None = None, **params: str) -> str:
    lines = ["version: 1", "repositories:", "  - url: ../apps.git"]  # beside the fleet repo
    if pin is not None:
        lines.append(f"    ref: {pin}")
    lines += ["app:", f"  name: {app}"]
    if params:
        lines += ["  params:"] + [f'    {k}: "{v}"' for k, v in params.items()]
    return "\n".join(lines) + "\n"


@pytest.fixture
def apps(make_repo: Callable[[str], RepoBuilder]) -> str:
    """The app repository beside the fleet's; its commit."""
    return apps_repo(make_repo("apps.git"))


@pytest.fixture
def fleet(make_repo: Callable[[str], RepoBuilder], apps: str) -> RepoBuilder:
    repo = make_repo("fleet.git")
    repo.commit("alpha for every car", {"desired-state.yaml": fleet_state("alpha", MODE="one")})
    repo.push()
    return repo


def following(root: Path, url: str, vehicle: str) -> Lpam:
    """A car under `root` whose agent.yaml follows `url` as `vehicle`."""
    lpam = Lpam(root)
    config = lpam.root / "etc/lpam/agent.yaml"
    config.parent.mkdir(parents=True)
    config.write_text(f"version: 1\nsource: {{url: {url}, branch: main}}\n"
                      f"vehicle: {vehicle}\n")
    return lpam


@pytest.fixture
def car(tmp_path: Path, git_daemon: GitDaemon) -> Lpam:
    return following(tmp_path / "root", git_daemon.url("fleet.git"), "rav4-07")


