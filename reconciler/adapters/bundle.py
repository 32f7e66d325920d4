"""Git bundles of the fleet, with dulwich's bundle support: one file holding the objects of
the desired-state repository's branch and of every commit it pins, with refs for the branch
and each pin, and a manifest blob saying which commit belongs to which repository. Git's
objects are content-addressed, so one pack holds many repositories.

What goes into a bundle, and what is done with one, is the bundle use case's
(workflow/bundle.py); this module only writes and reads the file, so that dulwich stays
behind the adapters (.importlinter).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout

if TYPE_CHECKING:
    from dulwich.bundle import Bundle
    from dulwich.object_store import BaseObjectStore
    from dulwich.repo import Repo

# Imported inside functions: dulwich loads only when a bundle is written or read; this module
# is itself imported only for that (workflow/bundle.py, lazily), so no real start-up gain.

MANIFEST = b"refs/lpam/manifest"
FORMAT = 1
REMAKE = "make one with `lpam bundle create`"


def write(layout: Layout, out: Path, *, branch: str, tip: str, manifest: dict[str, Any],
          pins: Sequence[tuple[str, str]]) -> None:
    """Write to `out` (atomically) the bundle of the store's repositories: `tip` of the
    source (key, commit first in `pins`) as `branch`, each other pin as refs/lpam/pins/<n>,
    and `manifest` (given its `format` here) as a blob."""
    from dulwich.bundle import create_bundle_from_repo, write_bundle
    from dulwich.objects import Blob, ObjectID
    from dulwich.refs import Ref
    from dulwich.repo import Repo

    from reconciler.adapters import history

    with tempfile.TemporaryDirectory(prefix="lpam-bundle-") as tmp, \
            Repo.init_bare(tmp) as pack:
        for key, commit in pins:
            with Repo(str(layout.repository_dir(key))) as source:
                count, records = source.generate_pack_data(
                    have=set(), want={ObjectID(commit.encode("ascii"))})
                pack.object_store.add_pack_data(count, records)
        # an app's commit fetched one deep comes without its parents: say where to stop
        history.mark(pack, [ObjectID(commit.encode("ascii")) for _, commit in pins])
        body = {"format": FORMAT, **manifest}
        blob = Blob.from_string(json.dumps(body, indent=2, sort_keys=True).encode())
        pack.object_store.add_object(blob)
        pack.refs[Ref(f"refs/heads/{branch}".encode())] = ObjectID(tip.encode("ascii"))
        pack.refs[Ref(MANIFEST)] = blob.id
        for number, (_, commit) in enumerate(pins[1:]):
            pack.refs[Ref(f"refs/lpam/pins/{number}".encode())] = \
                ObjectID(commit.encode("ascii"))
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


@contextmanager
def opened(path: Path) -> Iterator[tuple[dict[str, Any], Repo]]:
    """The bundle at `path`: its manifest (checked) and a temporary repository holding its
    objects, which `GitStore.adopt` takes them from; ConfigError for a file that is not a
    bundle lpam wrote."""
    from dulwich.bundle import read_bundle
    from dulwich.refs import Ref
    from dulwich.repo import Repo

    from reconciler.adapters import history

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
                              hint=REMAKE) from None
        try:
            _store(bundle, pack.object_store, path)
            manifest_id = bundle.references.get(Ref(MANIFEST))
            history.mark(pack, bundle.references.values())
        finally:
            _release(bundle)
        if manifest_id is None:
            raise ConfigError("this git bundle has no lpam manifest", path=path, hint=REMAKE)
        yield _manifest(pack.object_store[manifest_id].as_raw_string(), path), pack


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
                          hint=REMAKE)
    store.add_objects([(obj, None) for obj in PackInflater.for_pack_data(data)])


def _release(bundle: Bundle) -> None:
    """Close the bundle's pack data: dulwich >= 0.25 keeps it open until `close()`; 0.24,
    the last dulwich for Python 3.9, reads it whole and has no `close`."""
    close = getattr(bundle, "close", None)
    if close is not None:
        close()
