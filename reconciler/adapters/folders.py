"""The app folders on the machine's disk: the AppFolders port (engine/execution/ports.py) over
reconciler/engine/records/generations.py (the generation folders and their metadata) and
reconciler/engine/records/legacy/appdir.py (the `/etc/libpanda.d/apps` links and LPAM's manifest).

The engine changes those folders only through this port, so that what it does to the disk
is chosen, like every other side effect, by the workflow that builds its context.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

from reconciler.base.layout import Layout
from reconciler.core.planning.model import Generation, GenerationKey
from reconciler.engine.execution.ports import Store
from reconciler.engine.records import generations
from reconciler.engine.records.legacy import appdir
from schemas.record import StateRecord


@dataclass(frozen=True)
class DiskFolders:
    """The app folders under `layout`'s root; generations are exported from `store`."""

    layout: Layout
    store: Store

    def stage(self, gen: Generation) -> Path:
        return generations.stage(self.layout, self.store, gen)

    def ensure(self, gen: Generation) -> Path:
        return generations.ensure(self.layout, self.store, gen)

    def meta(self, app: str, generation: str) -> Generation | None:
        return generations.read_meta(self.layout.generation_meta(app, generation))

    def present(self) -> frozenset[GenerationKey]:
        return generations.present(self.layout)

    def installed(self) -> list[Generation]:
        return generations.installed_on_disk(self.layout)

    def prune(self, keep: Collection[GenerationKey]) -> None:
        generations.prune(self.layout, keep)

    def point(self, folder: str, target: Path) -> Path:
        return appdir.point(self.layout, folder, target)

    def release(self, folder: str, target: Path) -> None:
        appdir.release(self.layout, folder, target)

    def set_current(self, folder: str | None) -> None:
        appdir.set_current(self.layout, folder)

    def service_of(self, folder: Path) -> str | None:
        return appdir.service_of(folder)

    def keep_offered(self, record: StateRecord) -> None:
        appdir.keep_offered(self.layout, self.store, record)
