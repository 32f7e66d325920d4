"""Offline bundles: the fleet's desired state and everything it pins, on a USB stick.

`create` (on a laptop with network) fetches the desired-state repository's branch, reads
every desired state in it (`desired-state.yaml`, `vehicles/*.yaml`), resolves each to the
commits of its app and ROS repositories, and writes one git bundle (dulwich's bundle
support) holding all their objects, with refs for the branch and each pinned commit, and a
manifest blob saying which commit belongs to which repository (URL, store key, the ref it
resolved). Git's objects are content-addressed, so one pack holds many repositories.

`unpack` (on the car, no network) reads the bundle into the store as if each repository
had been fetched from its URL — the same origin, the same branch refs — after checking that
the bundle is of the source this car follows; `lpam sync --bundle` then verifies the
revision (its signature, with `trust:`) and applies it like any fetched one.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reconciler.errors import ConfigError, LpamError
from reconciler.workflow.defaults import FETCH_LOCK_TIMEOUT
from reconciler.workflow.events import Progress, Report
from reconciler.workflow.machine import Machine
from reconciler.workflow.sync import DEFAULT_FILE, SOURCE_KEY, VEHICLE_DIR, desired_at
from schemas.names import is_hex_commit

if TYPE_CHECKING:
    from dulwich.bundle import Bundle
    from dulwich.object_store import BaseObjectStore

MANIFEST = b"refs/lpam/manifest"
FORMAT = 1


@dataclass(frozen=True)
class Entry:
    """One repository the bundle carries: where it comes from, its store key, the commit,
    and the ref (as the remote names it: refs/heads/…, refs/tags/…) that resolved to it."""

    key: str
    url: str
    commit: str
    ref: str | None


def create(machine: Machine, url: str, branch: str, out: Path, *, report: Report,
           lock_timeout: float = FETCH_LOCK_TIMEOUT) -> int:
    """Write the bundle of `url`'s `branch` to `out`; how many repositories it holds."""
    from dulwich.bundle import create_bundle_from_repo, write_bundle
    from dulwich.objects import Blob, ObjectID
    from dulwich.refs import Ref
    from dulwich.repo import Repo

    from reconciler.atomic import write_atomic
    from reconciler.execution.lock import apply_lock

    store = machine.store()
    with apply_lock(machine.layout, timeout=lock_timeout):
        store.fetch(SOURCE_KEY, url)
        refs = store.local_refs(SOURCE_KEY)
        tip = None if refs is None else refs.resolve(branch)
        if tip is None:
            raise ConfigError(f"the source has no branch {branch!r}", path=url,
                              hint="name the branch the cars follow")
        entries = _pinned(machine, url, tip, report)
    with tempfile.TemporaryDirectory(prefix="lpam-bundle-") as tmp, \
            Repo.init_bare(tmp) as pack:
        for key, commit in [(SOURCE_KEY, tip), *((e.key, e.commit) for e in entries)]:
            with Repo(str(machine.layout.repository_dir(key))) as source:
                count, records = source.generate_pack_data(
                    have=set(), want={ObjectID(commit.encode("ascii"))})
                pack.object_store.add_pack_data(count, records)
        manifest = {"format": FORMAT, "source": {"url": url, "branch": branch, "commit": tip},
                    "repositories": [e.__dict__ for e in entries]}
        blob = Blob.from_string(json.dumps(manifest, indent=2, sort_keys=True).encode())
        pack.object_store.add_object(blob)
        pack.refs[Ref(f"refs/heads/{branch}".encode())] = ObjectID(tip.encode("ascii"))
        pack.refs[Ref(MANIFEST)] = blob.id
        for number, entry in enumerate(entries):
            pack.refs[Ref(f"refs/lpam/pins/{number}".encode())] = \
                ObjectID(entry.commit.encode("ascii"))
        named = [ref for ref in pack.refs if ref != b"HEAD"]  # HEAD names nothing here
        bundle = create_bundle_from_repo(pack, refs=named)
        try:
            partial = out.with_name(f".{out.name}.partial")
            with partial.open("wb") as stream:
                write_bundle(stream, bundle)
            write_atomic(out, partial.read_bytes())
            partial.unlink()
        finally:
            _release(bundle)
    report(Progress(f"bundle of {url} {branch} at {tip[:12]}: {len(entries)} repositories"))
    return len(entries)


def _pinned(machine: Machine, url: str, tip: str, report: Report) -> list[Entry]:
    """Every repository (app and ROS) that a desired state of the source at `tip` pins."""
    from reconciler.observe.targets import Fetch, resolve

    store = machine.store()
    names = [DEFAULT_FILE] + [f"{VEHICLE_DIR}/{n}" for n in
                              store.folder_files(SOURCE_KEY, tip, VEHICLE_DIR)
                              if n.endswith(".yaml")]
    found: dict[tuple[str, str], Entry] = {}
    for name in names:
        document = desired_at(machine, url, tip, name)
        if document is None:
            continue
        label, desired = document
        targets = resolve(desired, base_dir=Path("/"), store=store, fetch=Fetch.OBJECTS,
                          root=machine.layout.root)
        repos = list(targets.repositories)
        if targets.app is not None:
            repos += [r.repo for r in targets.app.deps.ros]
        for repo in repos:
            if repo.commit is None:
                raise LpamError(f"{label}: {repo.key} could not be resolved")
            found[(repo.key, repo.commit)] = Entry(repo.key, repo.url, repo.commit,
                                                   _ref_name(machine, repo.key, repo.ref))
        report(Progress(f"{name}: {len(repos)} repositories"))
    return sorted(found.values(), key=lambda e: (e.key, e.commit))


def _ref_name(machine: Machine, key: str, ref: str | None) -> str | None:
    """The full name a desired `ref` resolved through (None for a commit hash)."""
    if ref is not None and is_hex_commit(ref):
        return None
    refs = machine.store().local_refs(key)
    if refs is None:
        return None
    if ref is None:
        return f"refs/heads/{refs.default_branch}" if refs.default_branch else None
    for name in (f"refs/tags/{ref}", f"refs/heads/{ref}", ref):
        if name in refs.refs:
            return name
    return None


def unpack(machine: Machine, path: Path, url: str, branch: str, *,
           lock_timeout: float = FETCH_LOCK_TIMEOUT) -> str:
    """Bring the bundle at `path` into the store; the source revision it carries."""
    from dulwich.bundle import read_bundle
    from dulwich.refs import Ref
    from dulwich.repo import Repo

    from reconciler.execution.lock import apply_lock

    try:
        stream = path.open("rb")
    except OSError as exc:
        raise ConfigError(f"cannot read the bundle: {exc.strerror}", path=path) from None
    with stream, tempfile.TemporaryDirectory(prefix="lpam-unbundle-") as tmp, \
            Repo.init_bare(tmp) as pack:
        try:
            bundle = read_bundle(stream)
        except (ValueError, AssertionError, KeyError) as exc:
            raise ConfigError(f"not a git bundle lpam wrote: {exc}", path=path,
                              hint="make one with `lpam bundle create`") from None
        try:
            _store(bundle, pack.object_store, path)
            manifest_id = bundle.references.get(Ref(MANIFEST))
        finally:
            _release(bundle)
        if manifest_id is None:
            raise ConfigError("this git bundle has no lpam manifest", path=path,
                              hint="make one with `lpam bundle create`")
        manifest = _manifest(pack.object_store[manifest_id].as_raw_string(), path)
        source = manifest["source"]
        if (source["url"], source["branch"]) != (url, branch):
            raise ConfigError(f"this bundle is of {source['url']} ({source['branch']}); this "
                              f"car follows {url} ({branch})", path=path,
                              hint="make the bundle with --source set to the car's source")
        store = machine.store()
        with apply_lock(machine.layout, timeout=lock_timeout):
            store.adopt(SOURCE_KEY, url, pack, [source["commit"]],
                        {f"refs/remotes/origin/{branch}": source["commit"]})
            for entry in manifest["repositories"]:
                refs = {}
                ref = entry.get("ref")
                if isinstance(ref, str) and ref.startswith("refs/heads/"):
                    refs["refs/remotes/origin/" + ref.removeprefix("refs/heads/")] = \
                        entry["commit"]
                elif isinstance(ref, str) and ref.startswith("refs/tags/"):
                    refs[ref] = entry["commit"]
                store.adopt(entry["key"], entry["url"], pack, [entry["commit"]], refs)
        return str(source["commit"])


def _manifest(raw: bytes, path: Path) -> dict[str, Any]:
    try:
        data = json.loads(raw)
        if data.get("format") != FORMAT:
            raise ValueError(f"manifest format {data.get('format')!r}")
        source = data["source"]
        for entry in data["repositories"]:
            if not all(isinstance(entry.get(k), str) for k in ("key", "url", "commit")):
                raise ValueError("a repository entry lacks key, url or commit")
        if not all(isinstance(source.get(k), str) for k in ("url", "branch", "commit")):
            raise ValueError("the source lacks url, branch or commit")
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ConfigError(f"the bundle's manifest is not one lpam can read: {exc}",
                          path=path, hint="make the bundle again with this lpam") from None
    result: dict[str, Any] = data
    return result


def _store(bundle: Bundle, store: BaseObjectStore, path: Path) -> None:
    """Every object of the bundle into `store` as one pack, deltas resolved against the
    rest of the bundle. Not `Bundle.store_objects`: dulwich 0.24, the last for Python 3.9,
    skips deltified objects there (dulwich#2312), and 1.x writes each as a loose file."""
    from dulwich.pack import PackData, PackInflater

    data = bundle.pack_data
    if not isinstance(data, PackData):
        raise ConfigError("this git bundle holds no pack lpam can read", path=path,
                          hint="make one with `lpam bundle create`")
    store.add_objects([(obj, None) for obj in PackInflater.for_pack_data(data)])


def _release(bundle: Bundle) -> None:
    """Close the bundle's pack data: dulwich >= 0.25 keeps it open until `close()`; 0.24,
    the last dulwich for Python 3.9, reads it whole and has no `close`."""
    close = getattr(bundle, "close", None)
    if close is not None:
        close()
