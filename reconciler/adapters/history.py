"""Where a store's history is cut: the commits whose parents it does not hold.

Place in the flow: an app's repository is fetched one commit deep (`adapters.wire`), and
git (and dulwich) then list that commit in `.git/shallow`, so that nothing walks on to a
parent that is not there: the next fetch's negotiation, a pack made from the store. A
commit that arrives another way — adopted from a bundle (`GitStore.adopt`), copied into a
bundle (`adapters.bundle`) — is cut the same way, and its new repository must be told so,
or a walk through it fails on the missing parent.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from dulwich.objects import Commit, ObjectID
from dulwich.repo import Repo

from reconciler.base.atomic import fsync_dir


def boundary(repo: Repo, commits: Iterable[ObjectID]) -> set[ObjectID]:
    """The commits reachable from `commits` in `repo` that lack a parent there (or that
    `repo` already lists as shallow): where its history is cut."""
    store = repo.object_store
    listed = repo.get_shallow()
    cut: set[ObjectID] = set()
    seen: set[ObjectID] = set()
    todo = list(commits)
    while todo:
        sha = todo.pop()
        if sha in seen or sha not in store:
            continue
        seen.add(sha)
        found = store[sha]
        if sha in listed:
            cut.add(sha)
        elif isinstance(found, Commit):
            for parent in found.parents:
                if parent in store:
                    todo.append(parent)
                else:
                    cut.add(sha)
    return cut


def mark(repo: Repo, commits: Iterable[ObjectID]) -> None:
    """List in `repo`'s shallow file every cut reachable from `commits`, durably: on disk
    before refs name those commits (after a power cut, a ref to a commit whose missing
    parent is not listed would stop the next fetch)."""
    cut = boundary(repo, commits) - repo.get_shallow()
    if cut:
        repo.update_shallow(cut, None)
    durable(repo)


def durable(repo: Repo) -> None:
    """The shallow file, if any, fsynced with its folder."""
    listed = Path(repo.controldir()) / "shallow"
    if listed.exists():
        fd = os.open(listed, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        fsync_dir(listed.parent)
