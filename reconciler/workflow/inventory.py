"""The apps a car offers, as the field's tools show them: LPAM's `-d` table and the
phone's `A` (its `app_info` rows), made once here for both.

One row per app of every repository of the default desired state, read from the
repository store at the commit the desired state resolves to *without network* (a branch
as the last fetch left it): the table answers at once in a staging area with no WiFi,
and while an apply runs. The rows themselves are `lpam status`'s (reconciler/report/status.py:
files read from committed blobs, never a checkout; a damaged copy does not fail the
table), so both say the same thing; a repository never fetched has no row yet. Every
installed app is enabled (a car runs several side by side since issue 22: a controller
that owns the panda beside a recorder and a tracker); whether each runs is asked of its
service manager.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import LpamError
from reconciler.workflow import override
from reconciler.workflow.machine import Machine

if TYPE_CHECKING:
    from reconciler.adapters.git import GitStore
    from schemas.desired import DesiredState, RepositorySpec
    from schemas.record import RepositoryRecord

NO_APP_STATE = "inactive (none installed)"  # LPAM's `-t` without an app


@dataclass(frozen=True)
class AppRow:
    """An app as LPAM's table and the phone show it. `enabled`: it is an installed app;
    `running`: its service manager says it runs (always False for the others)."""

    repository: str  # `owner/repo` for a GitHub shorthand, else the repository's name
    branch: str  # the ref the desired state asks for; "(default)": the default branch
    app: str  # the app's name (its folder's, as LPAM named apps)
    service: str  # the unit its `service` file names, or lpam's own unit; "" when none
    enabled: bool
    running: bool
    description: str  # the first line of description.txt (or the catalog's description)


def app_table(machine: Machine) -> list[AppRow]:
    """Every app of every repository of the default desired state, offline; each
    installed app enabled (several run side by side since issue 22), at its catalog's
    place, or last when the catalog no longer lists it."""
    from reconciler.base.loading import load
    from reconciler.core.documents import desired_from
    from reconciler.engine.records.state import read_record
    from reconciler.report import status

    found = override.editable(machine)
    desired = desired_from(load(found.path, found.text))
    store = machine.store()
    record = read_record(machine.layout)
    repositories = [r for r in (_offline(machine, store, desired, spec, found.path)
                                for spec in desired.repositories) if r is not None]
    lives = {a.name: machine.services.state(a.service) for a in record.apps if a.service}
    rows = status.rows(machine.layout, store=store, lives=lives,
                       record=record.model_copy(update={"repositories": repositories}))
    return [AppRow(repository=r.repository, branch=r.ref, app=r.app,
                   service="" if r.service == "-" else r.service, enabled=r.installed,
                   running=r.running, description=r.description)
            for r in rows if r.installed or r.app != "-"]  # "-": a note, not an app


def _offline(machine: Machine, store: GitStore, desired: DesiredState, spec: RepositorySpec,
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


def current_apps(machine: Machine) -> list[str]:
    """The installed apps' names, in the order they were installed (LPAM's `current:`,
    which named one); empty when there is none."""
    from reconciler.engine.records.state import read_record

    return [app.name for app in read_record(machine.layout).apps]


def service_state(machine: Machine) -> str:
    """Each installed app's unit as its service manager sees it now, one a line (LPAM's
    `-t`, which had one app)."""
    from reconciler.engine.records.state import read_record

    apps = read_record(machine.layout).apps
    if not apps:
        return NO_APP_STATE
    return "\n".join(machine.services.state(app.service).describe() if app.service else
                     f"{app.name} names no service: lpam records it {app.status}"
                     for app in apps)
