"""Reading a clone of the desired-state repository that is not lpam's store (a laptop's
`git clone` of the fleet repository): the branches the cars push their status to.

`lpam fleet status` (workflow/fleet.py) shows them; this module is the dulwich side of it,
so that dulwich stays behind the adapters (.importlinter).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from reconciler.base.errors import ConfigError

# Imported inside functions: dulwich loads only when `lpam fleet` reads a published clone
# (start-up: importing this module stays dulwich-free).


@dataclass(frozen=True)
class Published:
    """One file a car published: the name after the branch's prefix, the file's bytes, and
    its commit's time (epoch seconds)."""

    name: str
    content: bytes
    commit_time: int


def published(repo_path: Path, *, branch: str, prefixes: Sequence[bytes],
              file: bytes) -> tuple[str | None, list[Published]]:
    """(the tip of `branch` — the remote's, else the local one —, `file` at the tip of every
    branch under one of `prefixes`, in the order of the branches' full names). A name may
    come twice (a local and a remote branch): which counts is the caller's choice. A branch
    whose tip does not hold the file is left out."""
    from dulwich.errors import NotGitRepository
    from dulwich.objects import Blob, Commit, Tree
    from dulwich.refs import Ref
    from dulwich.repo import Repo

    try:
        repo = Repo(str(repo_path))
    except NotGitRepository:
        raise ConfigError("not a clone of the desired-state repository", path=repo_path,
                          hint="run it in a clone (git clone …; git fetch) or pass --repo") \
            from None
    with repo:
        refs = repo.get_refs()
        tip_id = refs.get(Ref(f"refs/remotes/origin/{branch}".encode())) or \
            refs.get(Ref(f"refs/heads/{branch}".encode()))
        found: list[Published] = []
        for ref, sha in sorted(refs.items()):
            prefix = next((p for p in prefixes if ref.startswith(p)), None)
            if prefix is None or sha is None:
                continue
            name = ref[len(prefix):].decode("utf-8", "replace")
            commit = repo[sha]
            if not isinstance(commit, Commit):
                continue
            tree = repo[commit.tree]
            assert isinstance(tree, Tree)
            try:
                _, blob_id = tree[file]
            except KeyError:
                continue
            blob = repo[blob_id]
            if isinstance(blob, Blob):
                found.append(Published(name, blob.as_raw_string(), commit.commit_time))
    return (tip_id.decode("ascii") if tip_id else None), found


def read_at(repo_path: Path, commit: str, path: str) -> bytes | None:
    """The file `path` at `commit` of the clone (None when either is absent)."""
    from dulwich.errors import NotGitRepository
    from dulwich.object_store import tree_lookup_path
    from dulwich.objects import Blob, Commit, ObjectID
    from dulwich.repo import Repo

    try:
        repo = Repo(str(repo_path))
    except NotGitRepository:
        return None
    with repo:
        try:
            found = repo[ObjectID(commit.encode("ascii"))]
            if not isinstance(found, Commit):
                return None
            _, sha = tree_lookup_path(repo.__getitem__, found.tree, path.encode())
            blob = repo[sha]
        except (KeyError, ValueError):
            return None
        return blob.as_raw_string() if isinstance(blob, Blob) else None
