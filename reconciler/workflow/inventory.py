"""The apps a car offers, as the field's tools show them: LPAM's `-d/-l/-c/-t` and the
phone's `A` (its `app_info` rows) render one status report (schemas/report.py), made here.

Its rows are every app of every repository of the default desired state, read from the
repository store at the commit the desired state resolves to *without network* (a branch
as the last fetch left it): the table answers at once in a staging area with no WiFi,
and while an apply runs. The report is `lpam status`'s (reconciler/report/: files read
from committed blobs, never a checkout; a damaged copy does not fail the table) over
those repositories, so both say the same thing; a repository never fetched has no row
yet. Every installed app is enabled (a car runs several side by side since issue 22: a
controller that owns the panda beside a recorder and a tracker); whether each runs is
asked of its service manager.

The store read here is `adapters.objectfiles.ObjectFiles`: the desired state is resolved,
each copy checked and its files read from git's own files, without importing dulwich
(issue 32: the table is asked often, on a Pi); what those files cannot answer for certain
is asked of `GitStore`, as before.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import LpamError
from reconciler.workflow import override
from reconciler.workflow.machine import Machine

if TYPE_CHECKING:
    from reconciler.adapters.objectfiles import ObjectFiles
    from schemas.desired import DesiredState, RepositorySpec
    from schemas.record import RepositoryRecord
    from schemas.report import StatusReport

# Imported inside functions: the store readers and schemas (pydantic) load only when a report is
# made; the shim and BLE import this module lazily already (small gain).


def report(machine: Machine) -> StatusReport:
    """The status report over the repositories of the default desired state, offline:
    its `apps` are the table's rows, its `installed` the apps that are enabled."""
    from reconciler.adapters.objectfiles import ObjectFiles
    from reconciler.base.loading import load
    from reconciler.core.documents import desired_from
    from reconciler.engine.records.state import read_record
    from reconciler.report import status

    found = override.editable(machine)
    desired = desired_from(load(found.path, found.text))
    store = ObjectFiles(machine.layout)
    record = read_record(machine.layout)
    repositories = [r for r in (_offline(machine, store, desired, spec, found.path)
                                for spec in desired.repositories) if r is not None]
    return status.report(machine.layout, store=store, state=machine.services.state,
                         record=record.model_copy(update={"repositories": repositories}))


def _offline(machine: Machine, store: ObjectFiles, desired: DesiredState, spec: RepositorySpec,
             path: Path) -> RepositoryRecord | None:
    """The commit `spec` resolves to with no network, as a record's entry (None: not
    known here yet, or its copy is damaged: no rows until an apply fetches it)."""
    from reconciler.engine.observe.targets import Fetch, resolve
    from schemas.record import RepositoryRecord

    alone = desired.model_copy(update={"repositories": [spec], "apps": []})
    try:
        target = resolve(alone, base_dir=path.resolve().parent, store=store,
                         fetch=Fetch.OFFLINE, root=machine.layout.root).repositories[0]
    except LpamError:
        return None
    if target.commit is None:
        return None
    return RepositoryRecord(key=target.key, url=target.url, ref=target.ref,
                            commit=target.commit, applied=target.commit)
