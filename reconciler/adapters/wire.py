"""The network conversation with a remote, run in a child process that can be killed.

Place in the flow: `adapters.remote.Transport` has `adapters.deadline` fork a child that
runs `serve` for every `ls_remote` and fetch, and kills the child's whole process group when
the `--network-timeout` deadline passes or lpam is interrupted. dulwich has no total-time bound
(its git:// client has no timeout at all, HTTP retries multiply the per-socket one, `ssh`
waits as long as the ssh binary does, and a server dripping one byte at a time never trips
a per-read timeout), so killing a process is the only bound that holds on every transport.

Protocol, owned by this module: the child gets one request (`{"op": "ls-remote"|"fetch"|
"push", ...}`) and answers with one JSON document on its pipe, either `{"refs": {...},
"head": ...}` (a push: `{"pushed": ref}`) or `{"error": "one line"}`, with `"refused": true`
when a push reached the repository and it does not accept it from us (read-only, no write
access, a protected branch) rather than the network failing. A child whose pipe reaches
end of file has lost lpam (killed) and kills its own group, so no ssh or fetch outlives
lpam.

A fetch only adds a pack to the repository's object store (dulwich writes it to a temporary
file and renames it into place when complete); the parent writes refs after the child has
succeeded, so a child killed half-way changes nothing that lpam reads. The pack, its index
and their folder are fsynced before the child answers: refs written after a power cut
must not name objects the cut took back (a pack still in the page cache comes back empty,
and the store would be damaged).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import signal
import socket
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Mapping
from collections.abc import Set as AbstractSet
from fnmatch import fnmatchcase
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

from dulwich.errors import GitProtocolError, NotGitRepository
from dulwich.object_store import DiskObjectStore, peel_sha
from dulwich.objects import ObjectID
from dulwich.refs import Ref
from dulwich.repo import Repo

from reconciler.adapters import history
from reconciler.base.atomic import fsync_dir

if TYPE_CHECKING:
    from multiprocessing.connection import Connection

    from dulwich.client import GitClient
    from dulwich.pack import UnpackedObject

# Imported inside functions: dulwich.client (5 modules more than the top imports) loads where a
# client is made or its errors named, mostly in the network child; a small start-up gain.

_WANTED = (b"refs/heads/", b"refs/tags/")
_PEELED = b"^{}"


def client_for(url: str) -> tuple[GitClient, str]:
    """A dulwich client for a URL or absolute path that `Transport` has already checked.

    Local repositories get `LocalGitClient` directly: `get_transport_and_path` would send
    a path containing ':' to the ssh binary and open a plain file to sniff for a bundle.
    """
    from dulwich.client import LocalGitClient, get_transport_and_path

    parsed = urlparse(url)
    if "://" not in url:
        return LocalGitClient(), url
    if parsed.scheme == "file":
        return LocalGitClient(), parsed.path
    return get_transport_and_path(url)


def ls_remote(url: str) -> dict[str, Any]:
    """Every branch and tag the remote advertises, with `^{}` entries for annotated tags."""
    from dulwich.client import LocalGitClient

    client, path = client_for(url)
    result = client.get_refs(path.encode("utf-8"))
    refs = _text_refs(result.refs)
    if isinstance(client, LocalGitClient):  # local repositories do not send peeled tags
        refs.update(_peel_local(path, refs))
    head = result.symrefs.get(Ref(b"HEAD"))
    return {"refs": refs, "head": head.decode("utf-8", "replace") if head else None}


def fetch(url: str, repo_path: str, skip: str = "", want: str = "", keep: str = "",
          ) -> dict[str, Any]:
    """Fetch into `repo_path` (refs stay untouched; the parent writes them) either the
    commit `want` alone — its tree, nothing older (depth 1) — or, without `want`, every
    branch and tag with their history (but those under `skip`, such as the fleet's status
    branches). The answer: the advertised refs, the bytes of pack the server sent, and
    whether what came is shallow.

    An app's repository is fetched for one pinned commit, whose history lpam never reads,
    over what may be a phone's hotspot: `want` asks for that commit by its hash, which
    protocol v2 servers (GitHub, git daemon) and v0 servers with
    uploadpack.allowReachableSHA1InWant grant. An older server refuses a commit it does not
    advertise as a tip: then the tips are fetched with their whole history (a shallow store
    deepened to full), the one way such a server gives an older commit.

    `keep`: globs, one per line, of names under `skip` fetched all the same (a car in a
    rollout reads the status branches of the cars in the waves before its own, not the
    whole fleet's)."""
    client, path = client_for(url)
    skipped = skip.encode("utf-8")
    kept = [glob for glob in keep.splitlines() if glob]

    def passed(name: str) -> bool:
        return not (skip and name.startswith(skip)) or \
            any(fnmatchcase(name[len(skip):], glob) for glob in kept)
    with Repo(repo_path) as repo:
        durable(repo)
        target = ObjectID(want.encode("ascii")) if want else None

        def tips(refs: Mapping[Ref, ObjectID | None], depth: int | None = None,
                 ) -> list[ObjectID]:
            found = [sha for name, sha in refs.items() if sha is not None and _is_tip(name)
                     and (not (skipped and name.startswith(skipped))
                          or passed(name.decode("utf-8", "replace")))]
            return [sha for sha in dict.fromkeys(found) if deepen or sha not in repo.object_store]

        def commit(refs: Mapping[Ref, ObjectID | None], depth: int | None = None,
                   ) -> list[ObjectID]:
            return [] if target is None or target in repo.object_store else [target]

        deepen = False
        if target is None:
            result, brought = _fetch(client, path, repo, tips, None)
        else:
            try:
                result, brought = _fetch(client, path, repo, commit, 1)
            except GitProtocolError:  # "not our ref": a server that grants tips only
                deepen = bool(repo.get_shallow())
                result, brought = _fetch(client, path, repo, tips, _FULL if deepen else None)
        packs = os.path.join(repo_path, ".git", "objects", "pack")
        if os.path.isdir(packs):
            fsync_dir(Path(packs))  # the renames that put the pack and its index in place
        shallow = target is not None and target in repo.get_shallow()
    advertised = _text_refs(result.refs)
    refs = {name: sha for name, sha in advertised.items()
            if not name.endswith(_PEELED.decode()) and passed(name)}
    peeled = {name[: -len(_PEELED)]: sha for name, sha in advertised.items()
              if name.endswith(_PEELED.decode())}
    if shallow and not peeled and any(name.startswith("refs/tags/") for name in refs):
        peeled = _peeled(client, path, refs)
    return {"refs": refs, "peeled": peeled, "bytes": brought, "shallow": shallow}


def _peeled(client: GitClient, path: str, refs: dict[str, str]) -> dict[str, str]:
    """Each annotated tag's commit. A shallow fetch brings no tag object, so the parent
    names a tag by its commit; protocol v2's fetch lists refs unpeeled, so ask the list
    again with them (a local repository: peel them here)."""
    from dulwich.client import LocalGitClient

    if isinstance(client, LocalGitClient):
        listed = _peel_local(path, refs)
    else:
        listed = _text_refs(client.get_refs(path.encode("utf-8")).refs)
    return {name[: -len(_PEELED)]: sha for name, sha in listed.items()
            if name.endswith(_PEELED.decode())}


_FULL = 2**31 - 1
"""The depth that makes a shallow store whole again (git's `fetch --unshallow` asks it)."""


def _fetch(client: GitClient, path: str, repo: Repo,
           wants: Callable[..., list[ObjectID]], depth: int | None) -> tuple[Any, int]:
    """One fetch into `repo`: the server's answer and the bytes of pack it sent.

    dulwich's `GitClient.fetch` tells the server only the commits under refs/heads, which
    lpam does not keep (its checkouts are detached, the remote's branches under
    refs/remotes/origin): the server then sends every object again. The walker here
    offers every commit a ref (HEAD included) names, so a new commit brings what the
    store lacks and nothing more. A local repository is copied by dulwich directly."""
    from dulwich.client import LocalGitClient

    if isinstance(client, LocalGitClient):
        before = _pack_bytes(repo)
        result = client.fetch(path.encode("utf-8"), repo, determine_wants=wants, depth=depth)
        return result, _pack_bytes(repo) - before
    brought = 0
    spool = os.fspath(repo.object_store.path)
    with tempfile.SpooledTemporaryFile(max_size=_SPOOL, dir=spool) as pack:

        def write(data: bytes) -> int:
            nonlocal brought
            brought += len(data)
            return pack.write(data)

        walker = repo.get_graph_walker(heads=_heads(repo))
        result = client.fetch_pack(path.encode("utf-8"), wants, walker, write, depth=depth)
        if pack.tell():
            pack.seek(0)
            repo.object_store.add_thin_pack(pack.read, None)
    repo.update_shallow(result.new_shallow, result.new_unshallow)
    history.durable(repo)
    return result, brought


_SPOOL = 16 * 1024 * 1024  # a pack up to this size is held in memory, a larger one on disk


def _heads(repo: Repo) -> list[ObjectID]:
    """Every commit a ref of `repo` names (tags peeled) and every commit fetched alone
    (listed as shallow: a pinned commit no branch names any more), for the server to
    leave out what they hold."""
    heads = []
    for sha in dict.fromkeys([*repo.get_refs().values(), *sorted(repo.get_shallow())]):
        if sha in repo.object_store:
            with contextlib.suppress(KeyError):
                heads.append(peel_sha(repo.object_store, sha)[1].id)
    return list(dict.fromkeys(heads))


def _pack_bytes(repo: Repo) -> int:
    packs = Path(repo.object_store.path) / "pack"
    return sum(p.stat().st_size for p in packs.glob("*.pack")) if packs.is_dir() else 0


def durable(repo: Repo) -> None:
    """Have `repo` fsync each pack, pack index and loose object it writes (git's
    core.fsyncObjectFiles), so that what names them later is never written first."""
    store = repo.object_store
    if isinstance(store, DiskObjectStore):
        store.fsync_object_files = True


def push(url: str, repo_path: str, ref: str, new: str) -> dict[str, Any]:
    """Set `ref` on the remote to `new` (a commit of `repo_path`), sending what it lacks."""
    client, path = client_for(url)
    with Repo(repo_path) as repo:

        def update(refs: dict[Ref, ObjectID]) -> dict[Ref, ObjectID]:
            return {**refs, Ref(ref.encode("utf-8")): ObjectID(new.encode("ascii"))}

        def pack(have: AbstractSet[ObjectID], want: AbstractSet[ObjectID], *,
                 ofs_delta: bool = False, progress: Callable[[bytes], None] | None = None,
                 ) -> tuple[int, Iterator[UnpackedObject]]:
            return repo.generate_pack_data(set(have), set(want), ofs_delta=ofs_delta)

        result = client.send_pack(path.encode("utf-8"), update, generate_pack_data=pack)
    refused = {name.decode("utf-8", "replace"): why for name, why in
               (result.ref_status or {}).items() if why is not None}
    if refused:  # the server got the update and declined it: a refusal, whatever its words
        return {"error": "; ".join(f"{name}: {why}" for name, why in refused.items()),
                "refused": True}
    return {"pushed": ref}


_REFUSALS = ("denied", "not exported", "service not enabled", "forbidden", "not allowed",
             "read-only", "read only", "unauthorized", "no valid credentials",
             "authentication", "http resp 401", "http resp 403", "declined",
             "protected branch")
"""How servers say that they do not take a push from this client, lower-cased: git
daemon without receive-pack ("access denied or repository not exported", with
--informative-errors "service not enabled"), GitHub and GitLab over ssh ("Permission to
… denied", "not allowed to push"), HTTP 401 and 403, hooks ("pre-receive hook declined")."""


def refusal(exc: BaseException) -> bool:
    """Whether a failed push was refused by the repository (read-only for this client, no
    write access, a protected branch): asking again every few minutes cannot help, unlike
    a network that failed. Judged on the whole message (ssh puts the server's words on any
    of its stderr lines)."""
    from dulwich.client import HTTPUnauthorized

    if isinstance(exc, HTTPUnauthorized):
        return True
    text = str(exc).lower()
    return any(words in text for words in _REFUSALS)


def _is_tip(name: bytes) -> bool:
    return name.startswith(_WANTED) and not name.endswith(_PEELED)


def _text_refs(refs: Mapping[Ref, ObjectID | None]) -> dict[str, str]:
    """Branches and tags as text; a name that is not UTF-8 cannot be asked for in a desired
    state, so it is left out rather than carried as bytes through JSON."""
    text = {}
    for name, sha in refs.items():
        if sha is None or not name.startswith(_WANTED):
            continue
        try:
            text[name.decode("utf-8")] = sha.decode("ascii")
        except UnicodeDecodeError:
            continue
    return text


def _peel_local(path: str, refs: dict[str, str]) -> dict[str, str]:
    """The `^{}` entries a local repository does not advertise: annotated tags peeled."""
    peeled = {}
    with Repo(path) as repo:
        for name, sha in refs.items():
            if name.startswith("refs/tags/") and not name.endswith("^{}"):
                target = peel_sha(repo.object_store, ObjectID(sha.encode("ascii")))[1].id
                if target.decode("ascii") != sha:
                    peeled[name + "^{}"] = target.decode("ascii")
    return peeled


def _transport_errors() -> tuple[type[Exception], ...]:
    from dulwich.client import HTTPProxyUnauthorized, HTTPUnauthorized, StrangeHostname

    return (OSError, GitProtocolError, NotGitRepository, HTTPUnauthorized,
            HTTPProxyUnauthorized, StrangeHostname)


_ERRNO_WORDS = {
    errno.ECONNREFUSED: "the server refused the connection (nothing listens at {where})",
    errno.ECONNRESET: "the server at {where} closed the connection",
    errno.ETIMEDOUT: "the connection to {where} timed out",
    errno.ENETUNREACH: "the network is unreachable (is this machine offline?)",
    errno.EHOSTUNREACH: "the host {host} is unreachable",
    errno.ENETDOWN: "the network is down (is this machine offline?)",
}


def reason(exc: BaseException, url: str = "") -> str:
    """One line saying why a transport failed, in words (never a library's repr such as
    urllib3's `HTTPConnectionPool(...): Max retries exceeded` or `[Errno 111]`); the parent
    adds what failed (fetching URL) and what to try."""
    from dulwich.client import StrangeHostname

    if isinstance(exc, StrangeHostname):
        return "the host name looks like a command-line option"
    parsed = urlparse(url)
    host = parsed.hostname or "the server"
    try:
        port = parsed.port
    except ValueError:
        port = None
    where = f"{host}:{port}" if port else host
    cause = _os_cause(exc)
    if isinstance(cause, socket.gaierror):
        return f"the host name {host} is not known (no DNS answer; is this machine offline?)"
    if isinstance(cause, socket.timeout) and cause.errno is None:
        return f"the connection to {where} timed out"
    if cause is not None and cause.errno in _ERRNO_WORDS:
        return _ERRNO_WORDS[cause.errno].format(where=where, host=host)
    if cause is not None and cause.strerror:
        return f"{cause.strerror.lower()} ({where})"
    return _one_line(str(exc)) or type(exc).__name__


def _os_cause(exc: BaseException) -> OSError | None:
    """The operating system's error beneath a transport failure: dulwich wraps urllib3's
    MaxRetryError, whose `reason` wraps the socket's error."""
    seen: set[int] = set()
    todo: list[BaseException | None] = [exc]
    while todo:
        current = todo.pop(0)
        if current is None or id(current) in seen:
            continue
        seen.add(id(current))
        if isinstance(current, OSError) and (current.errno is not None
                                             or isinstance(current, socket.timeout)):
            return current
        reason_ = getattr(current, "reason", None)
        todo += [reason_ if isinstance(reason_, BaseException) else None,
                 current.__cause__, current.__context__]
    return None


def _one_line(text: str) -> str:
    """A library's or a server's text as one line without its `[Errno N]` prefix or a
    trailing full stop (the message it ends up in adds its own)."""
    line = next((part.strip() for part in text.splitlines() if part.strip()), "")
    line = re.sub(r"\[Errno -?\d+\]\s*", "", line)
    return "".join(c if c.isprintable() else " " for c in line).rstrip(". ")


def _die_with_lpam(conn: Connection) -> None:
    """lpam never writes to the child: the pipe becomes readable only at end of file, when
    lpam has closed it or died. Then take the whole group (an ssh too) along."""
    with contextlib.suppress(OSError, EOFError):
        conn.poll(None)
    with contextlib.suppress(OSError):
        os.killpg(os.getpgrp(), signal.SIGKILL)
    os._exit(1)


def _terminated(signum: int, frame: object) -> None:
    # SystemExit unwinds through dulwich, which then deletes its half-written pack file.
    sys.exit(128 + signum)


def answer(request: dict[str, str]) -> dict[str, Any]:
    """The answer to one request: refs, or a one-line error."""
    try:
        if request["op"] == "ls-remote":
            return ls_remote(request["url"])
        if request["op"] == "push":
            return push(request["url"], request["repo"], request["ref"], request["new"])
        return fetch(request["url"], request["repo"], request.get("skip", ""),
                     request.get("want", ""), request.get("keep", ""))
    except _transport_errors() as exc:
        if request["op"] == "push" and refusal(exc):
            return {"error": reason(exc, request["url"]), "refused": True}
        return {"error": reason(exc, request["url"])}
    except Exception as exc:  # a hostile server's garbage, or a bug: one line
        return {"error": f"unexpected {type(exc).__name__} in the git client: "
                f"{reason(exc, request['url'])}"}


def serve(conn: Connection, request: dict[str, str], env: dict[str, str]) -> None:
    """The child's whole life (forked by `adapters.deadline`): its own session and group,
    lpam's environment as it is now (the forkserver's is from when it started: PATH, HOME,
    proxies may differ), one answer on `conn`."""
    os.setsid()
    os.environ.clear()
    os.environ.update(env)
    signal.signal(signal.SIGTERM, _terminated)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # lpam decides; it ends the group itself
    threading.Thread(target=_die_with_lpam, args=(conn,), daemon=True).start()
    conn.send_bytes(json.dumps(answer(request)).encode("utf-8"))
