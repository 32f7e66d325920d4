"""The remotes the checkouts come from: the network side of the repository store.

Place in the flow: `GitStore` (`adapters.git`) owns one `Transport` and delegates every
network step to it. `plan` may ask `ls_remote` what a branch or tag points to, returned
as a `RemoteRefs`; `apply`'s prepare phase fetches through `fetch_into` (the only network
step, done before the running app is touched). Transport failures of every kind become
one-line `GitError`s here. Nothing is written on disk but the fetched pack and the
mirrored refs of the checkout `GitStore` hands in.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING
from urllib.parse import urlparse

from dulwich.errors import GitProtocolError, NotGitRepository
from dulwich.object_store import peel_sha
from dulwich.objects import ObjectID
from dulwich.refs import Ref
from dulwich.repo import Repo

from reconciler.errors import GitError
from schemas.names import is_hex_commit

if TYPE_CHECKING:
    from dulwich.client import GitClient

# dulwich.client is imported where it is used (as dulwich.porcelain is in adapters.git): a
# no-op plan of pinned repositories reads the store only and should not pay for the network
# stack.

_HEADS = "refs/heads/"
_TAGS = "refs/tags/"
_PEELED = "^{}"
_SCHEMES = ("git", "http", "https", "ssh", "file")
_NETWORK_HINT = "check the URL and the network; nothing on the machine was changed"


def _transport_errors() -> tuple[type[Exception], ...]:
    from dulwich.client import HTTPProxyUnauthorized, HTTPUnauthorized, StrangeHostname

    return (OSError, GitProtocolError, NotGitRepository, HTTPUnauthorized,
            HTTPProxyUnauthorized, StrangeHostname)


@dataclass(frozen=True)
class RemoteRefs:
    """What a remote advertises: branch and tag tips (tags peeled to their commit)."""

    url: str
    refs: dict[str, str]
    default_branch: str | None

    def resolve(self, ref: str | None) -> str | None:
        """The commit `ref` names on the remote, or None.

        Short names are tried as a tag before a branch, the order `git rev-parse` uses, so
        that lpam and a user's git agree on an ambiguous name.
        """
        if ref is None:
            return self.refs.get(_HEADS + self.default_branch) if self.default_branch else None
        for name in (ref, _TAGS + ref, _HEADS + ref):
            if name.startswith("refs/") and name in self.refs:
                return self.refs[name]
        if len(ref) == 40 and is_hex_commit(ref) and ref in self.refs.values():
            return ref
        return None


class Transport:
    """dulwich's clients for the remotes, every wait bounded by `timeout` seconds."""

    def __init__(self, timeout: float) -> None:
        self._timeout = timeout

    def ls_remote(self, url: str) -> RemoteRefs:
        client, path = self._client(url)
        with self._network(url, "list the branches and tags of"):
            result = client.get_refs(path.encode("utf-8"))
            advertised = {
                name.decode("utf-8"): sha.decode("ascii")
                for name, sha in result.refs.items()
                if sha is not None
            }
            from dulwich.client import LocalGitClient

            if isinstance(client, LocalGitClient):  # local repositories do not send peeled tags
                advertised.update(_peel_local(path, advertised))
        refs = {
            name: advertised.get(name + _PEELED, sha)
            for name, sha in advertised.items()
            if name.startswith((_HEADS, _TAGS)) and not name.endswith(_PEELED)
        }
        head = result.symrefs.get(Ref(b"HEAD"), b"").decode("utf-8")
        if head.startswith(_HEADS) and head in refs:
            default: str | None = head[len(_HEADS) :]
        else:
            default = next((b for b in ("main", "master") if _HEADS + b in refs), None)
        return RemoteRefs(url=url, refs=refs, default_branch=default)

    def fetch_into(self, repo: Repo, url: str, *, mirror: bool = True) -> None:
        """Fetch every branch and tag, then mirror them as origin's refs and local tags.

        The refs are written only after the pack is safely stored, so a failed fetch
        changes nothing; `porcelain.fetch(repo, URL)` would not write them at all. With
        `mirror=False` (a URL that is not the checkout's origin) the origin's refs stay,
        and the fetched tips are kept under `refs/lpam/fetched/` so no cleanup drops them.
        """
        client, path = self._client(url)

        def wanted(refs: Mapping[Ref, ObjectID], depth: int | None = None) -> list[ObjectID]:
            tips = [*_under(refs, b"refs/heads/").values(), *_under(refs, b"refs/tags/").values()]
            return [sha for sha in dict.fromkeys(tips) if sha and sha not in repo.object_store]

        with self._network(url, "fetch"):
            result = client.fetch(path.encode("utf-8"), repo, determine_wants=wanted)
        heads, tags = _under(result.refs, b"refs/heads/"), _under(result.refs, b"refs/tags/")
        if not mirror:
            repo.refs.import_refs(Ref(b"refs/lpam/fetched/heads"), heads, prune=True)
            repo.refs.import_refs(Ref(b"refs/lpam/fetched/tags"), tags, prune=True)
            return
        repo.refs.import_refs(Ref(b"refs/remotes/origin"), heads, prune=True)
        repo.refs.import_refs(Ref(b"refs/tags"), tags)

    def _client(self, url: str) -> tuple[GitClient, str]:
        """A dulwich client for `url`, refusing what it would misparse or crash on."""
        parsed = urlparse(url)
        if "://" in url:
            if parsed.scheme not in _SCHEMES or (parsed.scheme != "file" and not parsed.hostname):
                raise GitError(f"'{url}' is not a git URL lpam can use", hint=_NETWORK_HINT)
        elif not os.path.isabs(url):
            raise GitError(
                f"'{url}' is neither a URL nor an absolute path",
                hint="use an https://, git://, ssh:// or file:// URL, or an absolute path",
            )
        pool = None
        if parsed.scheme in ("http", "https"):  # urllib3 takes the timeout the git:// path lacks
            import urllib3
            from dulwich.client import default_urllib3_manager

            manager = default_urllib3_manager(None, timeout=self._timeout)
            pool = manager if isinstance(manager, urllib3.PoolManager) else None
        with self._network(url, "connect to"):
            from dulwich.client import get_transport_and_path

            return get_transport_and_path(url, pool_manager=pool)

    @contextlib.contextmanager
    def _network(self, url: str, action: str) -> Iterator[None]:
        """Turn transport failures into one-line GitErrors (the bound on every wait is the
        socket default timeout set in GitStore.__init__)."""
        try:
            yield
        except _transport_errors() as exc:
            from dulwich.client import StrangeHostname

            if isinstance(exc, TimeoutError) or isinstance(exc.__cause__, TimeoutError):
                reason = f"no answer within {self._timeout:g} s"  # dulwich wraps it in its own
            elif isinstance(exc, StrangeHostname):
                reason = "the host name looks like a command-line option"
            else:
                reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise GitError(f"cannot {action} {url}: {reason}", hint=_NETWORK_HINT) from exc


def _under(refs: Mapping[Ref, ObjectID | None], prefix: bytes) -> dict[Ref, ObjectID | None]:
    """The refs below `prefix`, named relative to it, without peeled `^{}` entries."""
    return {
        Ref(name[len(prefix) :]): sha
        for name, sha in refs.items()
        if sha is not None and name.startswith(prefix) and not name.endswith(b"^{}")
    }


def _peel_local(path: str, refs: dict[str, str]) -> dict[str, str]:
    """The `^{}` entries a local repository does not advertise: annotated tags peeled."""
    peeled = {}
    with Repo(path) as repo:
        for name, sha in refs.items():
            if name.startswith(_TAGS) and not name.endswith(_PEELED):
                target = peel_sha(repo.object_store, ObjectID(sha.encode("ascii")))[1].id
                if target.decode("ascii") != sha:
                    peeled[name + _PEELED] = target.decode("ascii")
    return peeled
