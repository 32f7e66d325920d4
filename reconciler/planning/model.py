"""The values the pure planning core works on.

`Targets` is the desired state resolved to commits (by observe/targets.py, which may ask a
remote); `Observed` is what the read-only probes saw on the machine. Both are plain frozen
values, so the diff and the step graph can be tested without git, disk or processes.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import NamedTuple

from reconciler.layout import slug
from schemas.record import StateRecord

UNKNOWN = "(known after fetch)"  # a value a plan cannot know without the network


class GenerationKey(NamedTuple):
    """A generation folder on disk: (the app's folder name, the generation id).

    Typed and built in one place (`of`) so that an app name and the folder it lives in
    are never compared as loose strings (`alpha.` lives in `alpha`; comparing the name to
    the folder reinstalled it on every apply)."""

    folder: str
    generation: str

    @classmethod
    def of(cls, app: str, generation: str) -> GenerationKey:
        return cls(slug(app), generation)


@dataclass(frozen=True)
class RepoTarget:
    """A desired repository; `commit` is None only when it is known after a fetch.
    `as_of_last_fetch`: the branch or tag was resolved offline, from what the last fetch
    saw; the remote may have moved since."""

    key: str
    url: str
    ref: str | None
    commit: str | None
    as_of_last_fetch: bool = False


@dataclass(frozen=True)
class AppTarget:
    """The desired app. `tree`/`path` are None when its commit is not fetched yet."""

    name: str
    repository: str
    commit: str | None
    path: str | None
    tree: str | None
    params: dict[str, str] = field(default_factory=dict)

    @property
    def generation(self) -> str | None:
        """Generation id: the app folder's content plus its parameters, nothing else."""
        if self.tree is None:
            return None
        return generation_id(self.tree, self.params)


@dataclass(frozen=True)
class Targets:
    repositories: tuple[RepoTarget, ...]
    app: AppTarget | None


@dataclass(frozen=True)
class RepoObserved:
    """A checkout in the repository store as the probe found it."""

    key: str
    present: bool
    head: str | None = None
    origin: str | None = None
    local_edits: tuple[str, ...] = ()


@dataclass(frozen=True)
class Observed:
    record: StateRecord
    repositories: dict[str, RepoObserved]
    generations: frozenset[GenerationKey] = frozenset()
    interrupted: tuple[str, ...] = ()


def generation_id(tree: str, params: dict[str, str]) -> str:
    digest = hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()
    return f"{tree[:12]}-{digest[:8]}"


def short(commit: str | None) -> str:
    return commit[:12] if commit else UNKNOWN
