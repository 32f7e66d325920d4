"""The repository store: lpam's only conversation with git, through dulwich.

Place in the flow: `observe` reads checkouts here without network (`head`, `local_edits`,
`resolve_local`, `read_file`); `plan` may ask `ls_remote` what a branch or tag points to;
`apply`'s prepare phase calls `fetch` (the only network step, done before the running app
is touched), then `checkout` and `export_folder`, which copies an app folder into an
immutable generation.

On disk it owns `layout.repositories`: one ordinary git checkout per repository key
(`refs/remotes/origin/*` and `refs/tags/*` mirror the remote, HEAD is detached at the
commit lpam chose). Work in progress lives in siblings named `.<slug>~clone~*` and
`.<slug>~old~*` so that a power cut never leaves half a checkout under the key's own
name; leftovers are swept on the next fetch. A checkout interrupted by a power cut is
marked by `.git/lpam-checkout` so that its half-written files are not mistaken for a
user's edits. A commit whose tree holds a path git must never write (`.git`, `..`, their
case, NTFS and HFS+ spellings) is refused before anything is written, so that marker never
names such a commit and the store stays usable until a clean commit arrives.

The store is a cache of the remotes. A read of a checkout that fails is checked by
`adapters.integrity`: damage (a truncated pack, a lost index) is a `StoreDamagedError`
naming the repository and what is wrong, anything else stays the bug it is. `damage` runs
that check up front (plan and apply ask before they read a repository), and `renew`
replaces a damaged checkout with a fresh clone, keeping the old one as `.<slug>~damaged`
(its working tree may hold a user's edits, which a damaged index cannot tell).

The network side (what a remote advertises, fetching into a checkout) is
`adapters.remote.Transport`; this module owns the checkouts and reads their objects.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path

from dulwich.errors import NotTreeError
from dulwich.index import (
    build_file_from_blob,
    validate_path_element_default,
    validate_path_element_hfs,
    validate_path_element_ntfs,
)
from dulwich.object_store import iter_tree_contents
from dulwich.objects import Blob, Commit, ObjectID, SubmoduleEncountered, Tree
from dulwich.refs import Ref
from dulwich.repo import Repo

from reconciler.adapters import gitfiles, history, integrity
from reconciler.adapters.objectsize import object_size, too_large
from reconciler.adapters.remote import RemoteRefs, Transport
from reconciler.adapters.wire import durable
from reconciler.base.atomic import fsync_dir, write_atomic
from reconciler.base.errors import (
    GitError,
    LocalEditsError,
    LpamError,
    RefNotFoundError,
    StoreDamagedError,
)
from reconciler.base.layout import Layout, slug
from reconciler.base.reading import MIB
from reconciler.base.text import escaped
from reconciler.engine.execution.ports import READ_LIMIT, Fetched, ambiguous
from schemas.names import is_hex_commit, redact

# Imported inside functions: dulwich.porcelain (~50 modules beyond the dulwich loaded above)
# loads only for a checkout or a local-edits check; dulwich.index is loaded above (no gain).

BLOBS_LIMIT = 10_000  # files in one app folder; more is not an app folder to compare

# dulwich.porcelain is imported where it is used, as dulwich.client is in adapters.remote: a
# no-op plan of pinned repositories reads the store only and should not pay for the network
# stack.

__all__ = ["READ_LIMIT", "GitStore", "RemoteRefs"]

_MARKER = "lpam-checkout"
FILE_LIMIT = 100 * MIB
"""The largest file lpam writes out of git. dulwich inflates a blob whole in memory to
write it, so a 600 MB file would exhaust a Pi's; GitHub refuses files over 100 MiB too,
so no app repository served from there holds one."""


class GitStore:
    """The checkouts under `layout.repositories`, and the remotes they come from."""

    def __init__(
        self, layout: Layout, *, timeout: float = 60.0, file_limit: int = FILE_LIMIT
    ) -> None:
        """`timeout` bounds each network operation's total time (see adapters.remote);
        no file larger than `file_limit` is checked out or exported."""
        self._layout = layout
        self._transport = Transport(timeout)
        self._file_limit = file_limit

    # -- read-only, no network ---------------------------------------------------------

    def head(self, key: str) -> str | None:
        """The commit HEAD names. A detached HEAD (every checkout lpam made) is read from
        its file, as git writes it: one repository open fewer per repository and
        command; anything else is asked of dulwich."""
        with contextlib.suppress(OSError, UnicodeDecodeError):
            text = (self._layout.repository_dir(key) / ".git" / "HEAD").read_text("ascii")
            if len(text) == 41 and text.endswith("\n") and is_hex_commit(text[:40]):
                return text[:40]
        with self._open(key) as repo:
            if repo is None:
                return None
            try:
                return repo.refs[Ref(b"HEAD")].decode("ascii")
            except KeyError:  # a fresh clone: HEAD names a branch that was never made
                return None

    def origin_url(self, key: str) -> str | None:
        """origin's URL, from a config of the plain shape read without dulwich
        (adapters/gitfiles.py), else through dulwich."""
        git = self._layout.repository_dir(key) / ".git"
        if not git.is_dir():
            return None
        with contextlib.suppress(Exception):  # gitfiles.Unsure, a failed read: dulwich's
            return gitfiles.origin_url(git)
        with self._open(key) as repo:
            with contextlib.suppress(KeyError):
                if repo is not None:
                    return str(repo.get_config().get((b"remote", b"origin"), b"url"), "utf-8")
            return None

    def location(self, key: str) -> Path:
        """Where the key's checkout is (or would be), for messages."""
        return self._layout.repository_dir(key)

    def damage(self, key: str) -> str | None:
        """What is wrong with the key's checkout (adapters.integrity); None when it is sound
        or absent. Reads every byte of the packs lpam did not write itself, so it is asked
        before a repository is used (plan, apply), or after a read failed (status), not on
        every read."""
        path = self._layout.repository_dir(key)
        if not (path / ".git").is_dir():
            return None
        return integrity.damage(path)

    def has_commit(self, key: str, commit: str) -> bool:
        with self._open(key) as repo:
            return repo is not None and _commit(repo, commit) is not None

    def resolve_local(self, key: str, ref: str) -> str | None:
        """Expand an abbreviated hash against the commits already fetched (no network)."""
        ref = ref.lower()
        if not is_hex_commit(ref):
            return None
        with self._open(key) as repo:
            if repo is None:
                return None
            found = sorted(
                {sha.decode("ascii") for sha in repo.object_store.iter_prefix(ref.encode())}
            )
            commits = [sha for sha in found if _commit(repo, sha) is not None]
        if len(commits) > 1:
            raise ambiguous(key, ref, commits)
        return commits[0] if commits else None

    def local_edits(self, key: str) -> list[str]:
        """Paths a checkout would overwrite or a removal would lose.

        Empty while an interrupted checkout is pending: those differences were written by
        lpam, and the next checkout finishes that job first.
        """
        with self._open(key) as repo:
            if repo is None or _marker(repo).exists():
                return []
            return _edits(repo)

    def read_file(
        self, key: str, commit: str, path: str, *, limit: int = READ_LIMIT
    ) -> bytes | None:
        """The regular file `commit:path` (a symlink is not followed: None), at most `limit`
        bytes; a larger blob is refused from its header, before it is inflated."""
        with self._open(key) as repo:
            found = None if repo is None else _lookup(repo, commit, path)
            if repo is None or found is None or not stat.S_ISREG(found[0]):
                return None
            size = object_size(repo.object_store, found[1])
            data = None
            if size is None:  # not cheaply known: read it, then judge
                data = repo.object_store[found[1]].as_raw_string()
                size = len(data)
            if size > limit:
                raise too_large(key, path, commit, size, limit)
            return data if data is not None else repo.object_store[found[1]].as_raw_string()

    def folder_tree(self, key: str, commit: str, folder: str) -> str | None:
        with self._open(key) as repo:
            tree_id = None if repo is None else _folder(repo, commit, folder)
        return None if tree_id is None else tree_id.decode("ascii")

    def folder_files(self, key: str, commit: str, folder: str) -> list[str]:
        """The names of the regular files directly in `commit:folder` ([] without it)."""
        with self._open(key) as repo:
            tree_id = None if repo is None else _folder(repo, commit, folder)
            if repo is None or tree_id is None:
                return []
            tree = repo.object_store[tree_id]
            assert isinstance(tree, Tree)
            return sorted(entry.path.decode("utf-8", "replace") for entry in tree.items()
                          if entry.mode is not None and stat.S_ISREG(entry.mode))

    def folder_blobs(self, key: str, commit: str, folder: str) -> dict[str, str] | None:
        """See the `Store` port: every file below `commit:folder` and its blob id."""
        with self._open(key) as repo:
            tree_id = None if repo is None else _folder(repo, commit, folder)
            if repo is None or tree_id is None:
                return None
            blobs: dict[str, str] = {}
            for entry in iter_tree_contents(repo.object_store, tree_id):
                assert entry.path is not None and entry.mode is not None and entry.sha is not None
                if stat.S_ISREG(entry.mode) or stat.S_ISLNK(entry.mode):
                    blobs[entry.path.decode("utf-8", "replace")] = entry.sha.decode("ascii")
                    if len(blobs) > BLOBS_LIMIT:
                        return None
            return blobs

    def signature(self, key: str, commit: str) -> tuple[bytes | None, bytes]:
        """The commit's signature (its `gpgsig` header, None when unsigned) and what was
        signed (the commit object without that header)."""
        with self._open(key) as repo:
            found = None if repo is None else _commit(repo, commit)
            if found is None:
                raise RefNotFoundError(f"{key}: commit {commit} is not in the repository store")
            return found.gpgsig, found.raw_without_sig()

    def local_refs(self, key: str) -> RemoteRefs | None:
        """What the last fetch saw of origin's branches and tags (peeled), without network:
        the answer `plan --offline` gives instead of an ls-remote. None without a checkout."""
        with self._open(key) as repo:
            if repo is None:
                return None
            refs = {"refs/heads/" + name.decode("utf-8"): sha.decode("ascii")
                    for name, sha in repo.refs.as_dict(Ref(b"refs/remotes/origin")).items()}
            for name in repo.refs.as_dict(Ref(b"refs/tags")):
                with contextlib.suppress(KeyError):
                    peeled = repo.get_peeled(Ref(b"refs/tags/" + name))
                    refs["refs/tags/" + name.decode("utf-8")] = peeled.decode("ascii")
            url = self.origin_url(key) or ""
        default = next((b for b in ("main", "master") if "refs/heads/" + b in refs), None)
        return RemoteRefs(url=url, refs=refs, default_branch=default)

    # -- network, read-only -------------------------------------------------------------

    def ls_remote(self, url: str) -> RemoteRefs:
        return self._transport.ls_remote(url)

    # -- writes -------------------------------------------------------------------------

    def fetch(self, key: str, url: str, *, skip: str = "", want: str | None = None,
              keep: tuple[str, ...] = ()) -> Fetched:
        """Bring `key` up to date with `url`, cloning it when absent or when the URL changed:
        the commit `want` alone (depth 1: an app's pinned tree, not its years of history),
        or every branch and tag with their history (the fleet's repository, whose history
        its signatures and status need); refs under `skip` (the fleet's status branches)
        are not fetched, but those whose names below `skip` match a glob of `keep`. What
        came over the wire."""
        self._transport.check(url, "fetch")
        dest = self._checkout_dir(key)
        self._sweep(key)
        current = self.origin_url(key) if dest.exists() else None
        if current == url:
            with Repo(str(dest)) as repo:
                done = self._transport.fetch_into(repo, url, skip=skip, want=want,
                                                  keep=keep)
            integrity.remember(dest)
            return done
        if dest.exists():
            self._refuse_edits(key, "cannot switch it to " + redact(url))
        fresh, done = self._clone(key, url, skip=skip, want=want, keep=keep)
        try:
            if dest.exists():  # rename(2) may replace the empty directory _temp made
                os.rename(dest, self._temp(key, "old"))
            os.rename(fresh, dest)
        except BaseException:
            shutil.rmtree(fresh, ignore_errors=True)
            raise
        fsync_dir(dest.parent)
        self._sweep(key)
        return done

    def repoint(self, key: str, url: str) -> None:
        """See the `Store` port. The old origin's branches and tags move under
        refs/lpam/fetched/ (their objects stay reachable), then the config names `url`:
        after a power cut between the two, the next checkout repoints again. `url` is
        not reached, so not checked here (the desired state's validation refuses what
        could not be a git URL)."""
        self._sweep(key)
        with self._open(key) as repo:
            if repo is None:
                raise GitError(f"{key} is not in the repository store")
            heads = repo.refs.as_dict(Ref(b"refs/remotes/origin"))
            tags = repo.refs.as_dict(Ref(b"refs/tags"))
            repo.refs.import_refs(Ref(b"refs/lpam/fetched/heads"), heads, prune=True)
            repo.refs.import_refs(Ref(b"refs/lpam/fetched/tags"), tags, prune=True)
            for name in heads:
                repo.refs.remove_if_equals(Ref(b"refs/remotes/origin/" + name), None)
            for name in tags:
                repo.refs.remove_if_equals(Ref(b"refs/tags/" + name), None)
            config = repo.get_config()
            config.set((b"remote", b"origin"), b"url", url.encode("utf-8"))
            config.write_to_path()

    def renew(self, key: str, url: str) -> Path | None:
        """Clone `url` afresh in place of the key's checkout, which is kept aside (its
        path returned; None when there was none). The store is a cache: a damaged checkout
        is replaced, never repaired. Network first: when the clone fails, nothing moved.
        Each move is one rename, so after a power cut the key's checkout is the old one,
        the new one, or absent (then the next fetch clones it)."""
        self._transport.check(url, "fetch")
        dest = self._checkout_dir(key)
        self._sweep(key)
        fresh, _ = self._clone(key, url)
        try:
            aside = self._set_aside(key) if dest.exists() else None
            os.rename(fresh, dest)
        except BaseException:
            shutil.rmtree(fresh, ignore_errors=True)
            raise
        fsync_dir(dest.parent)
        return aside

    def adopt(self, key: str, url: str, source: Repo, commits: list[str],
              branches: dict[str, str]) -> None:
        """Bring `commits` (and what they reach) from the repository `source` (an unpacked
        bundle) into `key` as if fetched from `url`: a missing checkout is created with
        `url` as its origin, and `branches` (full ref name → commit, such as
        refs/remotes/origin/main or refs/tags/v1) are set as a fetch would leave them. A
        checkout with another origin gets the objects only."""
        dest = self._checkout_dir(key)
        self._sweep(key)
        if not dest.exists():
            fresh = self._temp(key, "clone")
            try:
                _init(fresh, url).close()
                os.rename(fresh, dest)
            except BaseException:
                shutil.rmtree(fresh, ignore_errors=True)
                raise
            fsync_dir(dest.parent)
        wanted = {ObjectID(c.encode("ascii")) for c in commits}
        with Repo(str(dest)) as repo:
            durable(repo)
            missing = {c for c in wanted if c not in repo.object_store}
            if missing:
                count, records = source.generate_pack_data(have=set(), want=missing)
                repo.object_store.add_pack_data(count, records)
                fsync_dir(dest / ".git" / "objects" / "pack")  # before refs name them
                history.mark(repo, missing)  # a commit a bundle brought one deep
                integrity.remember(dest)
            if self.origin_url(key) == url:
                for name, commit in branches.items():
                    repo.refs[Ref(name.encode())] = ObjectID(commit.encode("ascii"))

    def push_files(self, key: str, url: str, branch: str, files: Mapping[str, bytes],
                   message: str, *, when: int, parent: bool = True) -> str:
        """Commit `files` (name → content) as the whole tree of `branch` and push it to
        `url` in one connection; the new commit. With `parent`, the commit goes on top of
        the branch as the last fetch or push saw it on origin; without, it starts the
        branch afresh (the server decides whether it accepts that, see `Transport.push`).
        `when` is the commit's time (epoch seconds, from the caller's clock). Nothing in
        the checkout moves: the commit is made from objects alone."""
        self._sweep(key)
        with self._open(key) as repo:
            if repo is None:
                raise GitError(f"{key} is not in the repository store")
            blobs = {name: Blob.from_string(content) for name, content in files.items()}
            tree = Tree()
            for name, blob in blobs.items():
                tree.add(name.encode("utf-8"), 0o100644, blob.id)
            commit = Commit()
            commit.tree = tree.id
            tip = repo.refs.as_dict(Ref(b"refs/remotes/origin")).get(Ref(branch.encode()))
            commit.parents = [tip] if parent and tip is not None and tip in repo.object_store \
                else []
            commit.author = commit.committer = b"lpam <lpam@localhost>"
            commit.commit_time = commit.author_time = when
            commit.commit_timezone = commit.author_timezone = 0
            commit.message = message.encode("utf-8")
            durable(repo)
            for obj in (*blobs.values(), tree, commit):
                repo.object_store.add_object(obj)
            self._transport.push(repo, url, f"refs/heads/{branch}", commit.id.decode("ascii"))
            repo.refs[Ref(f"refs/remotes/origin/{branch}".encode())] = commit.id
            return commit.id.decode("ascii")

    def ancestors(self, key: str, commit: str, *, limit: int) -> list[str]:
        """`commit` and its first parents, newest first, at most `limit` (fewer where the
        store's history ends): what a car's agent compares a new revision with to tell a
        revert from a change."""
        found: list[str] = []
        with self._open(key) as repo:
            sha: str | None = commit
            while repo is not None and sha is not None and len(found) < limit:
                current = _commit(repo, sha)
                if current is None:
                    break
                found.append(sha)
                sha = current.parents[0].decode("ascii") if current.parents else None
        return found

    def history_length(self, key: str, branch: str, *, limit: int) -> int:
        """How many commits origin's `branch` holds as this store last saw it, counted along
        first parents up to `limit` (0 without the branch): enough to bound a branch this
        machine writes itself, with no network."""
        with self._open(key) as repo:
            if repo is None:
                return 0
            sha = repo.refs.as_dict(Ref(b"refs/remotes/origin")).get(Ref(branch.encode()))
            count = 0
            while sha is not None and count < limit:
                found = _commit(repo, sha.decode("ascii"))
                if found is None:
                    break
                count += 1
                sha = found.parents[0] if found.parents else None
            return count

    def fetch_objects(self, key: str, url: str, *, want: str | None = None) -> Fetched:
        """Bring `url`'s commits into the key's object database for a plan to read, moving
        no checkout: HEAD, index and files stay as they are. A missing checkout is created
        (a clone with nothing checked out, as `fetch` makes it); one with another origin
        keeps its origin and refs, the new commits being only added to its objects."""
        dest = self._checkout_dir(key)
        if not dest.exists() or self.origin_url(key) == url:
            return self.fetch(key, url, want=want)
        self._sweep(key)
        with Repo(str(dest)) as repo:
            done = self._transport.fetch_into(repo, url, mirror=False, want=want)
        integrity.remember(dest)
        return done

    def checkout(self, key: str, commit: str) -> None:
        """Detach HEAD at `commit` and make the index and working tree match it."""
        self._sweep(key)
        with self._open(key) as repo:
            found = None if repo is None else _commit(repo, commit)
            if repo is None or found is None:
                raise RefNotFoundError(
                    f"{key}: commit {commit} is not in the repository store",
                    hint="fetch the repository first, or check the commit hash",
                )
            unsafe = _unsafe_path(repo, found)
            if unsafe is not None:
                raise GitError(
                    f"{key}: commit {commit} has an unsafe path '{unsafe}'; "
                    "lpam will not check it out",
                    hint="the repository tries to write into git's own files or outside its "
                    "folder; push a commit without that path (lpam converges to it), or pin "
                    "another commit",
                )
            self._refuse_oversized(key, repo, commit, found.tree)
            marker = _marker(repo)
            if marker.exists():
                # A power cut stopped a checkout half-way, and HEAD (moved last) still names
                # where it started: switching to the recorded target rewrites exactly the
                # paths it was rewriting. Only then are remaining differences a user's. A
                # marker naming a commit that is gone or unsafe (written by an older lpam)
                # cannot be replayed; replaying it would block every later checkout.
                pending = marker.read_text(errors="replace").strip()
                target = _commit(repo, pending)
                if target is not None and _unsafe_path(repo, target) is None:
                    _checkout(repo, pending)
                marker.unlink()
            self._refuse_edits(key, f"cannot check out {commit[:12]}", repo=repo)
            write_atomic(marker, commit + "\n")
            # force: the tree was just found clean; only ignored files could still be in the way
            _checkout(repo, commit)
            marker.unlink()

    def remove(self, key: str) -> None:
        """Delete the key's checkout, refusing one with local edits; a damaged one, whose
        edits cannot be known, is kept aside instead (`.<slug>~damaged`)."""
        dest = self._checkout_dir(key)
        if not dest.exists():
            return
        try:
            self._refuse_edits(key, "cannot remove it")
        except StoreDamagedError:
            self._set_aside(key)
            fsync_dir(dest.parent)
            return
        doomed = self._temp(key, "old")
        os.rename(dest, doomed)  # one rename: the key's checkout is wholly there or gone
        fsync_dir(dest.parent)
        shutil.rmtree(doomed)

    def export_folder(self, key: str, commit: str, folder: str, dest: Path) -> str:
        """Copy `commit:folder` into the new directory `dest`; return the folder's tree sha.

        Files keep their exec bits and symlinks stay symlinks, exactly as git would check
        them out. A failed export removes `dest`. Durability of the copy (and renaming it
        into place) is the caller's business, since it owns the generation's layout.
        """
        with self._open(key) as repo:
            tree_id = None if repo is None else _folder(repo, commit, folder)
            if repo is None or tree_id is None:
                raise RefNotFoundError(
                    f"{key}: there is no folder '{folder}' at commit {commit}",
                    hint="check the app's folder in the app catalog at that commit",
                )
            self._refuse_oversized(key, repo, commit, tree_id)
            dest.mkdir(parents=True)
            root = os.fsencode(dest)
            try:
                for entry in iter_tree_contents(repo.object_store, tree_id):
                    assert entry.path is not None and entry.mode is not None
                    assert entry.sha is not None
                    if stat.S_ISDIR(entry.mode) or entry.mode == 0o160000:  # submodule
                        continue
                    target = _target(root, entry.path)
                    os.makedirs(os.path.dirname(target), exist_ok=True)
                    blob = repo.object_store[entry.sha]
                    assert isinstance(blob, Blob)
                    build_file_from_blob(blob, entry.mode, target)
            except _UnsafePath as exc:
                shutil.rmtree(dest, ignore_errors=True)
                raise GitError(
                    f"{key}: commit {commit} has an unsafe path {exc.args[0]!r} in '{folder}'",
                    hint="the repository tries to write outside the app folder; do not use it",
                ) from exc
            except BaseException:
                shutil.rmtree(dest, ignore_errors=True)
                raise
        return tree_id.decode("ascii")

    # -- helpers ------------------------------------------------------------------------

    def _refuse_oversized(self, key: str, repo: Repo, commit: str, tree: ObjectID) -> None:
        """Refuse a tree holding a file over the limit, judged from object headers only."""
        for entry in iter_tree_contents(repo.object_store, tree):
            assert entry.path is not None and entry.mode is not None and entry.sha is not None
            if not stat.S_ISREG(entry.mode):
                continue
            size = object_size(repo.object_store, entry.sha)
            if size is not None and size > self._file_limit:
                raise GitError(
                    f"{key}: commit {commit[:12]} holds '{_printable(entry.path)}' of "
                    f"{size // MIB} MiB; lpam writes no file over "
                    f"{self._file_limit // MIB} MiB out of git",
                    hint="keep large data (models, recordings) out of the app repository, "
                    "or pin another commit; nothing on the machine was changed",
                )

    def _checkout_dir(self, key: str) -> Path:
        """The key's directory, refusing to replace or delete something that is not lpam's."""
        path = self._layout.repository_dir(key)
        if path.exists() and not (path / ".git").is_dir():
            raise GitError(
                f"{path} is in the repository store but is not a git checkout",
                hint="move it elsewhere or delete it; lpam will then clone the repository there",
            )
        return path

    def _clone(self, key: str, url: str, *, skip: str = "", want: str | None = None,
               keep: tuple[str, ...] = ()) -> tuple[Path, Fetched]:
        """A new clone of `url` (nothing checked out) in a temporary sibling of the key's
        checkout, for the caller to rename into place; removed again if the fetch fails."""
        fresh = self._temp(key, "clone")
        try:
            with _init(fresh, url) as repo:
                done = self._transport.fetch_into(repo, url, skip=skip, want=want,
                                                  keep=keep)
            integrity.remember(fresh)
        except BaseException:
            shutil.rmtree(fresh, ignore_errors=True)
            raise
        return fresh, done

    def _set_aside(self, key: str) -> Path:
        """Move the key's checkout to `.<slug>~damaged` (one rename), replacing what an
        earlier damage left there: one copy is kept for a person to look at, not a pile."""
        aside = self._layout.repositories / f".{slug(key)}~damaged"
        if aside.exists():
            shutil.rmtree(aside)
        os.rename(self._layout.repository_dir(key), aside)
        return aside

    @contextlib.contextmanager
    def _open(self, key: str) -> Iterator[Repo | None]:
        """The checkout of `key`, closed afterwards (dulwich keeps pack files open). A read
        that fails on a damaged checkout is a StoreDamagedError naming the damage; a failure
        on a sound one is raised as it is (a bug, or the disk)."""
        path = self._layout.repository_dir(key)
        if not (path / ".git").is_dir():
            yield None
            return
        try:
            with Repo(str(path)) as repo:
                yield repo
        except LpamError:
            raise
        except Exception as exc:
            found = integrity.damage(path)
            if found is None:
                raise
            raise StoreDamagedError(key, found, path=path) from exc

    def _refuse_edits(self, key: str, doing: str, *, repo: Repo | None = None) -> None:
        edits = _edits(repo) if repo is not None else self.local_edits(key)
        if not edits:
            return
        path = self._layout.repository_dir(key)
        shown = ", ".join(edits[:5]) + (f" and {len(edits) - 5} more" if len(edits) > 5 else "")
        raise LocalEditsError(
            f"{key}: {doing}: {path} has local edits: {shown}",
            hint=f"commit and push them, or move them elsewhere, or delete {path} "
            "(lpam will fetch it again)",
        )

    def _temp(self, key: str, kind: str) -> Path:
        """A new sibling of the checkout; '~' never occurs in a slug, so sweeping is exact."""
        self._layout.repositories.mkdir(parents=True, exist_ok=True)
        prefix = f".{slug(key)}~{kind}~"
        return Path(tempfile.mkdtemp(prefix=prefix, dir=self._layout.repositories))

    def _sweep(self, key: str) -> None:
        """Remove what an interrupted fetch or removal of `key` left behind, and the lock
        files a killed write left in its checkout (`_stale_locks`)."""
        if not self._layout.repositories.is_dir():
            return
        for kind in ("clone", "old"):
            for leftover in self._layout.repositories.glob(f".{slug(key)}~{kind}~*"):
                shutil.rmtree(leftover, ignore_errors=True)
        _stale_locks(self._layout.repository_dir(key))


def _stale_locks(checkout: Path) -> None:
    """Remove the lock files a killed lpam left in `checkout`'s .git. dulwich, as git, writes
    a ref, HEAD, the index, the config or the shallow list as NAME.lock renamed over NAME;
    killed in between, NAME.lock stays and every later write of NAME is refused
    (FileLocked), so a kill at the wrong instant would leave the store unusable. lpam writes
    its store only under the apply lock (reconciler/workflow), and only the lock's holder
    calls this (before it writes): a lock file found then is no live writer's."""
    git = checkout / ".git"
    if not git.is_dir():
        return
    for folder, pattern in ((git, "*.lock"), (git / "refs", "**/*.lock"),
                            (git / "objects" / "pack", "*.lock")):
        for found in folder.glob(pattern):
            with contextlib.suppress(FileNotFoundError):
                found.unlink()


def _init(path: Path, url: str) -> Repo:
    """A new, empty repository at `path` whose origin is `url`, as `git clone` sets it up."""
    repo = Repo.init(str(path))
    config = repo.get_config()
    config.set((b"remote", b"origin"), b"url", url.encode("utf-8"))
    config.set((b"remote", b"origin"), b"fetch", b"+refs/heads/*:refs/remotes/origin/*")
    config.write_to_path()
    return repo


def _commit(repo: Repo, commit: str) -> Commit | None:
    if len(commit) != 40 or not is_hex_commit(commit):
        return None
    try:
        obj = repo.object_store[ObjectID(commit.encode("ascii"))]
    except KeyError:
        return None
    return obj if isinstance(obj, Commit) else None


def _lookup(repo: Repo, commit: str, path: str) -> tuple[int, ObjectID] | None:
    """(mode, sha) of `commit:path`; the commit's root tree for an empty path or '.'."""
    found = _commit(repo, commit)
    if found is None:
        return None
    clean = "/".join(part for part in path.split("/") if part not in ("", "."))
    tree = repo.object_store[found.tree]
    assert isinstance(tree, Tree)
    try:
        return tree.lookup_path(repo.object_store.__getitem__, clean.encode("utf-8"))
    except (KeyError, NotTreeError, SubmoduleEncountered):
        return None


def _folder(repo: Repo, commit: str, folder: str) -> ObjectID | None:
    """The tree id of `commit:folder`; None when there is no folder there."""
    found = _lookup(repo, commit, folder)
    return found[1] if found is not None and stat.S_ISDIR(found[0]) else None


def _checkout(repo: Repo, commit: str) -> None:
    from dulwich import index, porcelain

    found = _commit(repo, commit)
    planted = None if found is None else _planted_link(repo, found)
    dulwich_check = getattr(index, "InvalidPathError", None)  # dulwich >= 0.25 checks too
    refused: tuple[type[BaseException], ...] = (_UnsafePath,) if dulwich_check is None \
        else (_UnsafePath, dulwich_check)
    try:
        if planted is not None:
            raise _UnsafePath(os.fsencode(planted))
        porcelain.checkout(repo, commit, force=True)
    except refused as exc:
        raise GitError(
            f"cannot check out {commit[:12]} in {repo.path}: a symlink stands where the "
            f"commit has a folder ({_printable(exc.args[0]) if exc.args else exc})",
            hint=f"delete {repo.path} (lpam will fetch it again)",
        ) from exc
    if found is not None:
        _drop_stale_entries(repo, found)


def _drop_stale_entries(repo: Repo, commit: Commit) -> None:
    """Remove from the index the files `commit` does not have. dulwich 0.24 (the last for
    Python 3.9) keeps the entry of a file already gone from the working tree (a checkout
    cut off half-way), which would then read as a local edit at every later checkout."""
    index = repo.open_index()
    wanted = {entry.path for entry in iter_tree_contents(repo.object_store, commit.tree)}
    stale = [path for path in index if path not in wanted]
    for path in stale:
        del index[path]
    if stale:
        index.write()


def _planted_link(repo: Repo, commit: Commit) -> str | None:
    """The first folder of `commit` that is a symlink in the working tree: checking out
    through it would write outside the repository. Walks trees only, never a blob."""
    todo: list[tuple[bytes, ObjectID]] = [(b"", commit.tree)]
    while todo:
        prefix, tree_id = todo.pop()
        tree = repo.object_store[tree_id]
        assert isinstance(tree, Tree)
        for entry in tree.iteritems():
            assert entry.path is not None and entry.mode is not None and entry.sha is not None
            if stat.S_ISDIR(entry.mode):
                path = prefix + entry.path
                if os.path.islink(os.path.join(os.fsencode(repo.path), path)):
                    return os.fsdecode(path)
                todo.append((path + b"/", entry.sha))
    return None


class _UnsafePath(Exception):
    """A tree path that would be written outside its folder, or into git's own files."""


def _target(root: bytes, path: bytes) -> bytes:
    """Where the tree's `path` is written under `root`. Refused (`_UnsafePath`) when a part
    of it is a name git never writes (`.git`, `.`, `..`) or when it goes through a symlink
    that an earlier entry of the same (malformed) tree wrote: git's own rule, kept here
    whatever dulwich is installed (0.24, the last for Python 3.9, does not check it)."""
    parts = path.split(b"/")
    if not all(validate_path_element_default(part) for part in parts):
        raise _UnsafePath(path)
    here = root
    for part in parts[:-1]:
        here = os.path.join(here, part)
        if os.path.islink(here):
            raise _UnsafePath(path)
    return os.path.join(root, path)


def _safe_name(name: bytes) -> bool:
    """Whether git may write a tree entry called `name`, judged by every file system's rules
    git protects (a repository made elsewhere may aim at any of them): not `.git`, `.`,
    `..` or empty in any case, NTFS spelling (`git~1`, `.git.`, `.git::$INDEX_ALLOCATION`)
    or HFS+ spelling (with ignorable Unicode). A name that is not UTF-8 cannot be an HFS+
    spelling, and is an ordinary file name on the Pi's file system."""
    if b"/" in name or _ntfs_dotgit(name) or not validate_path_element_ntfs(name):
        return False
    try:
        name.decode("utf-8")
    except UnicodeDecodeError:
        return validate_path_element_default(name)
    return validate_path_element_hfs(name)


def _ntfs_dotgit(name: bytes) -> bool:
    """git's own `is_ntfs_dotgit`: a name NTFS would open as `.git` — `.GIT. `, `git~1`,
    `.git::$INDEX_ALLOCATION`, or any of them after a backslash. Kept here because
    dulwich 0.24 (the last for Python 3.9) checks only the plain spellings."""
    for segment in name.split(b"\\"):
        for prefix in (b".git", b"git~1"):
            if segment[: len(prefix)].lower() == prefix:
                rest = segment[len(prefix):].split(b":", 1)[0]  # an NTFS stream after ':'
                if not rest.strip(b" ."):
                    return True
    return False


def _unsafe_path(repo: Repo, commit: Commit) -> str | None:
    """The first path of `commit`'s tree that must not be written to a working tree, shown
    printable; None when every path is safe. Walks trees only, never reading a blob."""
    todo: list[tuple[bytes, ObjectID]] = [(b"", commit.tree)]
    while todo:
        prefix, tree_id = todo.pop()
        tree = repo.object_store[tree_id]
        if not isinstance(tree, Tree):
            return _printable(prefix.rstrip(b"/")) or "."
        for entry in tree.iteritems():
            assert entry.path is not None and entry.mode is not None and entry.sha is not None
            path = prefix + entry.path
            if not _safe_name(entry.path):
                return _printable(path)
            if stat.S_ISDIR(entry.mode):
                todo.append((path + b"/", entry.sha))
    return None


def _printable(path: bytes) -> str:
    """`path` for a one-line message: control characters escaped, never interpreted."""
    return escaped(path.decode("utf-8", "replace"))


def _edits(repo: Repo) -> list[str]:
    """Paths a user changed in the working tree. A clone never checked out (no index)
    holds nothing of the user's unless files were put beside `.git`."""
    from dulwich import porcelain

    if not os.path.exists(repo.index_path()):
        return sorted(e for e in os.listdir(repo.path) if e != ".git")
    status = porcelain.status(repo, untracked_files="all")
    paths: set[bytes] = set(status.unstaged) | set(status.untracked)
    for changed in status.staged.values():
        paths.update(changed)
    return sorted(os.fsdecode(p) for p in paths)


def _marker(repo: Repo) -> Path:
    return Path(repo.controldir()) / _MARKER
