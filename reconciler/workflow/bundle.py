"""Offline bundles: the fleet's desired state and everything it pins, on a USB stick.

`create` (on a laptop with network) fetches the desired-state repository's branch, reads
every desired state in it (`desired-state.yaml`, `vehicles/*.yaml`), resolves each to the
commits of its app and ROS repositories, and writes one git bundle of them all
(adapters/bundle.py), its manifest naming each commit's repository by URL, store key and
the ref it resolved.

`unpack` (on the car, no network) reads the bundle into the store as if each repository
had been fetched from its URL — the same origin, the same branch refs — after checking that
the bundle is of the source this car follows; `lpam sync --bundle` then verifies the
revision (its signature, with `trust:`) and applies it like any fetched one: a bundle is a
desired-state source (`BundleFile`) as the network is (workflow/source.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from reconciler.base.errors import ConfigError, LpamError
from reconciler.base.text import counted
from reconciler.workflow.defaults import FETCH_LOCK_TIMEOUT
from reconciler.workflow.events import Progress, Report
from reconciler.workflow.machine import Machine
from reconciler.workflow.source import DEFAULT_FILE, SOURCE_KEY, VEHICLE_DIR, desired_at
from schemas.agent import AgentConfig
from schemas.names import is_hex_commit

# Imported inside functions: the bundle adapter (dulwich), the lock and target resolution load
# only when a bundle is made or unpacked; sync imports this module at top (start-up).


@dataclass(frozen=True)
class Entry:
    """One repository the bundle carries: where it comes from, its store key, the commit,
    and the ref (as the remote names it: refs/heads/…, refs/tags/…) that resolved to it."""

    key: str
    url: str
    commit: str
    ref: str | None


def create(machine: Machine, url: str, branch: str, out: Path, *, report: Report) -> int:
    """Write the bundle of `url`'s `branch` to `out`; how many repositories it holds."""
    from reconciler.adapters import bundle
    from reconciler.engine.execution.lock import apply_lock

    store = machine.store()
    with apply_lock(machine.layout, timeout=FETCH_LOCK_TIMEOUT):
        store.fetch(SOURCE_KEY, url)
        refs = store.local_refs(SOURCE_KEY)
        tip = None if refs is None else refs.resolve(branch)
        if tip is None:
            raise ConfigError(f"the source has no branch {branch!r}", path=url,
                              hint="name the branch the cars follow")
        entries = _pinned(machine, url, tip, report)
    manifest = {"source": {"url": url, "branch": branch, "commit": tip},
                "repositories": [e.__dict__ for e in entries]}
    bundle.write(machine.layout, out, branch=branch, tip=tip, manifest=manifest,
                 pins=[(SOURCE_KEY, tip), *((e.key, e.commit) for e in entries)])
    pinned = counted(len(entries), "repository", "repositories")
    report(Progress(f"bundle of {url} {branch} at {tip[:12]}: {pinned}"))
    return len(entries)


def _pinned(machine: Machine, url: str, tip: str, report: Report) -> list[Entry]:
    """Every repository (app and ROS) that a desired state of the source at `tip` pins."""
    from reconciler.engine.observe.targets import Fetch, resolve

    store = machine.store()
    names = [DEFAULT_FILE] + [f"{VEHICLE_DIR}/{n}" for n in
                              store.folder_files(SOURCE_KEY, tip, VEHICLE_DIR)
                              if n.endswith(".yaml")]
    found: dict[tuple[str, str], Entry] = {}
    for name in names:
        document = desired_at(machine, url, tip, name)
        if document is None:
            continue
        label, desired = document.path, document.desired
        targets = resolve(desired, base_dir=Path("/"), store=store, fetch=Fetch.OBJECTS,
                          root=machine.layout.root)
        repos = list(targets.repositories)
        for app in targets.apps:
            repos += [r.repo for r in app.deps.ros]
        for repo in repos:
            if repo.commit is None:
                raise LpamError(f"{label}: {repo.key} could not be resolved")
            found[(repo.key, repo.commit)] = Entry(repo.key, repo.url, repo.commit,
                                                   _ref_name(machine, repo.key, repo.ref))
        report(Progress(f"{name}: {counted(len(repos), 'repository', 'repositories')}"))
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
    from reconciler.adapters import bundle
    from reconciler.engine.execution.lock import apply_lock

    with bundle.opened(path) as (manifest, pack):
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


@dataclass(frozen=True)
class BundleFile:
    """A bundle file as the desired-state source of one sync pass (`lpam sync --bundle`):
    no network, the source and what it pins unpacked into the store."""

    path: Path
    live = False  # a file: never "offline", whatever it holds is all there is

    def bring(self, machine: Machine, config: AgentConfig, report: Report, *,
              lock_timeout: float, keep: tuple[str, ...] = ()) -> str | None:
        unpack(machine, self.path, config.source.url, config.source.branch,
               lock_timeout=lock_timeout)
        return f"from the bundle {self.path}"
