"""Where a vehicle's desired state comes from: the desired-state repository, read in the
store at a revision, brought there by a `DesiredStateSource` — the network (a fetch of the
source's URL, workflow/sync.py `Remote`) or a bundle file carried on a USB stick
(workflow/bundle.py `BundleFile`). The sync and bundle use cases both read the source
through this module, so neither imports the other.

Relative `url:` paths in the desired state resolve against the source repository's own
URL, as git resolves a submodule's (`../apps.git` beside the fleet repository).
"""

from __future__ import annotations

import posixpath
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from reconciler.workflow.events import Report
from reconciler.workflow.machine import Machine
from schemas.agent import AgentConfig

if TYPE_CHECKING:
    from reconciler.core.documents import DesiredDocument
    from schemas.desired import DesiredState

# Imported inside functions: the document readers (~13 modules) load only when a desired state is
# read from a source; a small start-up gain.

SOURCE_KEY = "@source"  # the desired-state repository in the store: never an app's key
VEHICLE_DIR = "vehicles"
DEFAULT_FILE = "desired-state.yaml"


class DesiredStateSource(Protocol):
    """What brings the source's branch into the store for one sync pass."""

    @property
    def live(self) -> bool:
        """True for the network: being offline is then no fault of the revision, and the
        same revision is not applied again offline. False for a file: what it holds is
        all there is."""
        ...

    def bring(self, machine: Machine, config: AgentConfig, report: Report, *,
              lock_timeout: float, keep: tuple[str, ...] = ()) -> str | None:
        """Bring `config.source`'s branch (and for a bundle, what it pins) into the store,
        waiting at most `lock_timeout` s for the apply lock, with the status branches of
        the cars matching `keep` (workflow/waves.py); why the pass is not online (None: it
        fetched from the network)."""
        ...


def desired_at(machine: Machine, url: str, revision: str,
               name: str) -> DesiredDocument | None:
    """The desired state in the file `name` of the source at `revision` (None without it),
    relative URLs made absolute; faults are located as `fleet.git@c92f32f2ab56/<name>`
    (its `path`), its apps' places kept through the anchoring."""
    from dataclasses import replace

    from reconciler.base.loading import load
    from reconciler.core.documents import desired_document

    data = machine.store().read_file(SOURCE_KEY, revision, name)
    if data is None:
        return None
    label = Path(f"{url.rstrip('/').rsplit('/', 1)[-1]}@{revision[:12]}") / name
    found = desired_document(load(label, data.decode("utf-8", "replace")))
    return replace(found, desired=anchored(found.desired, url))


def anchored(desired: DesiredState, source: str) -> DesiredState:
    repos = []
    for spec in desired.repositories:
        if spec.url is not None and "://" not in spec.url and not spec.url.startswith("/"):
            spec = spec.model_copy(update={"url": join_url(source, spec.url)})
        repos.append(spec)
    return desired.model_copy(update={"repositories": repos})


def join_url(base: str, relative: str) -> str:
    """`relative` against the repository at `base`, as git joins a submodule's URL: from
    the repository's own location (`../apps.git` is its sibling)."""
    if "://" in base:
        scheme, rest = base.split("://", 1)
        host, _, path = rest.partition("/")
        joined = posixpath.normpath(posixpath.join("/" + path, relative))
        return f"{scheme}://{host}{joined}"
    return posixpath.normpath(posixpath.join(base, relative))
