"""The remotes the checkouts come from: the network side of the repository store.

Place in the flow: `GitStore` (`adapters.git`) owns one `Transport` and delegates every
network step to it. `plan` may ask `ls_remote` what a branch or tag points to, returned
as a `RemoteRefs`; `apply`'s prepare phase fetches through `fetch_into` (the only network
step, done before the running app is touched). Transport failures of every kind become
one-line `GitError`s here, with any credentials in the URL hidden.

`--network-timeout` is a deadline on each operation's total time: the dulwich work runs in
a child process (`adapters.wire`) that is killed with its whole process group when the
deadline passes (`adapters.deadline`); no per-socket timeout can bound a server that drips
one byte at a time, HTTP retries, or the ssh binary. A fetch's child only adds a pack to
the object store; the refs are written here, after the child succeeded and the objects they
name are found, so an interrupted fetch changes nothing lpam reads.
"""

from __future__ import annotations

import os
import stat
from typing import Any
from urllib.parse import urlparse

from dulwich.objects import ObjectID
from dulwich.refs import Ref
from dulwich.repo import Repo

from reconciler.base.errors import GitError, PushRefusedError
from reconciler.engine.execution.ports import Fetched
from reconciler.engine.execution.ports import RemoteRefs as RemoteRefs
from schemas.names import redact

# Imported inside functions: the deadline runner loads only when a network operation runs; it is
# light (no heavy library) and this module already loads dulwich, so the gain is small.

_HEADS = "refs/heads/"
_TAGS = "refs/tags/"
_PEELED = "^{}"
_SCHEMES = ("git", "http", "https", "ssh", "file")
_NETWORK_HINT = ("check the URL and the network, or preview without it: `lpam plan --offline`; "
                 "nothing on the machine was changed")


class Transport:
    """Network operations on remotes, each bounded in total by `timeout` seconds."""

    def __init__(self, timeout: float) -> None:
        self._timeout = timeout

    def check(self, url: str, action: str) -> None:
        """Refuse, before anything is read or written, a URL dulwich would misparse or crash
        on, and a local path that is not a directory (a FIFO or /dev/zero would be read
        forever); `action` completes "cannot … URL" in the message."""
        parsed = urlparse(url)
        if "://" in url:
            if parsed.scheme not in _SCHEMES or (parsed.scheme != "file" and not parsed.hostname):
                raise GitError(redact(f"'{url}' is not a git URL lpam can use"),
                               hint=_NETWORK_HINT)
            if parsed.scheme != "file":
                return
            path = parsed.path
        elif not os.path.isabs(url):
            raise GitError(
                redact(f"'{url}' is neither a URL nor an absolute path"),
                hint="use an https://, git://, ssh:// or file:// URL, or an absolute path",
            )
        else:
            path = url
        try:
            mode = os.stat(path).st_mode
        except OSError as exc:
            message = redact(f"cannot {action} {url}: {exc.strerror}")
            raise GitError(message, hint=_NETWORK_HINT) from None
        if not stat.S_ISDIR(mode):
            raise GitError(
                redact(f"cannot {action} {url}: it is not a directory, so not a git repository"),
                hint="a local url: names the directory of a git repository",
            )

    def ls_remote(self, url: str) -> RemoteRefs:
        action = "list the branches and tags of"
        self.check(url, action)
        answer = self._ask({"op": "ls-remote", "url": url}, url, action)
        advertised: dict[str, str] = answer["refs"]
        refs = {
            name: advertised.get(name + _PEELED, sha)
            for name, sha in advertised.items()
            if name.startswith((_HEADS, _TAGS)) and not name.endswith(_PEELED)
        }
        head = answer["head"] or ""
        if head.startswith(_HEADS) and head in refs:
            default: str | None = head[len(_HEADS) :]
        else:
            default = next((b for b in ("main", "master") if _HEADS + b in refs), None)
        return RemoteRefs(url=url, refs=refs, default_branch=default)

    def fetch_into(self, repo: Repo, url: str, *, mirror: bool = True, skip: str = "",
                   want: str | None = None, keep: tuple[str, ...] = ()) -> Fetched:
        """Fetch the commit `want` alone (depth 1), or every branch and tag (but those
        under `skip`) with their history; then mirror the branches and tags whose commits
        the store holds as origin's refs and local tags. What came, in bytes.

        The refs are written only after the pack is safely stored, so a failed fetch
        changes nothing; `porcelain.fetch(repo, URL)` would not write them at all. A
        branch whose tip was not fetched (a shallow fetch brings one commit) is not
        named: a ref to an absent object would make the store unreadable, and offline the
        branch is then "known after fetch", not the stale tip. An annotated tag whose tag
        object did not come names its commit. With `mirror=False` (a URL that is not the
        checkout's origin) the origin's refs stay, and the fetched tips are kept under
        `refs/lpam/fetched/` so no cleanup drops them.
        """
        self.check(url, "fetch")
        request = {"op": "fetch", "url": url, "repo": repo.path, "skip": skip,
                   "want": want or "", "keep": "\n".join(keep)}
        answer = self._ask(request, url, "fetch")
        refs: dict[str, str] = answer["refs"]
        peeled: dict[str, str] = answer.get("peeled", {})
        fetched = {name.encode("utf-8"): sha.encode("ascii") for name, sha in refs.items()}
        missing = [sha for sha in fetched.values() if ObjectID(sha) not in repo.object_store]
        if want is None and missing:  # refs to absent objects would make the store unreadable
            raise GitError(
                redact(f"cannot fetch {url}: the server did not send {missing[0].decode()}"),
                hint=_NETWORK_HINT,
            )
        if want is not None:
            fetched = _held(repo, fetched, peeled)
        heads, tags = _under(fetched, b"refs/heads/"), _under(fetched, b"refs/tags/")
        if skip.startswith("refs/heads/"):  # what lpam keeps of them itself stays, but
            kept = skip.removeprefix("refs/heads/").encode("utf-8")  # what came is newer
            for name, sha in repo.refs.as_dict(Ref(b"refs/remotes/origin")).items():
                if name.startswith(kept):
                    heads.setdefault(Ref(name), sha)
        done = Fetched(url=url, bytes=int(answer.get("bytes", 0)),
                       shallow=bool(answer.get("shallow")))
        if not mirror:
            repo.refs.import_refs(Ref(b"refs/lpam/fetched/heads"), heads, prune=True)
            repo.refs.import_refs(Ref(b"refs/lpam/fetched/tags"), tags, prune=True)
            return done
        repo.refs.import_refs(Ref(b"refs/remotes/origin"), heads, prune=True)
        repo.refs.import_refs(Ref(b"refs/tags"), tags)
        return done

    def push(self, repo: Repo, url: str, ref: str, new: str) -> None:
        """Set the remote's `ref` to the commit `new` of `repo`, sending what it lacks; a
        `PushRefusedError` when the repository does not take it from us (not a network
        failure). `new` need not descend from the remote's `ref`: whether that is allowed
        is the server's to say (git's receive.denyNonFastForwards, a protected branch)."""
        self.check(url, "push to")
        self._ask({"op": "push", "url": url, "repo": repo.path, "ref": ref, "new": new},
                  url, "push to")

    def _ask(self, request: dict[str, str], url: str, action: str) -> dict[str, Any]:
        """Run one operation in a child process; its answer, or a one-line GitError (a
        PushRefusedError when the child found a push refused)."""
        from reconciler.adapters import deadline

        def failed(reason: str) -> GitError:
            return GitError(redact(f"cannot {action} {url}: {reason}"), hint=_NETWORK_HINT)

        try:
            answer = deadline.run(request, timeout=self._timeout)
        except deadline.Expired:
            raise failed(f"no answer within {self._timeout:g} s") from None
        except OSError as exc:
            raise failed(f"cannot start the git client: {exc.strerror}") from None
        if answer is None:
            raise failed("the git client ended without an answer")
        if "error" in answer and answer.get("refused"):
            raise PushRefusedError(
                redact(f"{url} does not accept pushes from this machine ({answer['error']})"),
                hint="the repository is read-only here (a mirror, a daemon without "
                "receive-pack, a token or key without write access, a protected branch)")
        if "error" in answer:
            raise failed(str(answer["error"]))
        return answer


def _held(repo: Repo, refs: dict[bytes, bytes],
          peeled: dict[str, str]) -> dict[bytes, bytes]:
    """The refs whose objects `repo` holds; an annotated tag whose tag object it lacks,
    as its commit when the store holds that."""
    held = {}
    for name, sha in refs.items():
        if ObjectID(sha) in repo.object_store:
            held[name] = sha
            continue
        commit = peeled.get(name.decode("utf-8"), "").encode("ascii")
        if commit and ObjectID(commit) in repo.object_store:
            held[name] = commit
    return held


def _under(refs: dict[bytes, bytes], prefix: bytes) -> dict[Ref, ObjectID]:
    """The refs below `prefix`, named relative to it."""
    return {
        Ref(name[len(prefix) :]): ObjectID(sha)
        for name, sha in refs.items()
        if name.startswith(prefix)
    }
