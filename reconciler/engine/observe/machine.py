"""Read-only probes of the machine: the state record, the repository store, the staged
generations, the journal of an interrupted apply, and each installed app's unit as its
service manager reports it now (the live state: the record says what lpam last did, the
manager says what runs). Nothing here writes.

Local edits are only looked for in checkouts the plan may move or remove: scanning every
working tree on every plan would make a no-op plan pay for what it does not need.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.layout import Layout
from reconciler.core.planning.model import AppTarget, DepsObserved, Observed, RepoObserved, Targets
from reconciler.engine.observe.adoption import adoptable
from reconciler.engine.records import generations
from reconciler.engine.records.journal import interrupted_steps
from reconciler.engine.records.legacy import appdir
from reconciler.engine.records.state import read_record

if TYPE_CHECKING:
    from reconciler.base.unit import UnitState
    from reconciler.engine.execution.ports import DependencyPorts, Services, Store
    from schemas.record import StateRecord


def observe(layout: Layout, store: Store, targets: Targets,
            services: Services | None = None, deps: DependencyPorts | None = None) -> Observed:
    record = read_record(layout)
    wanted = {t.key: t for t in targets.repositories}
    keys = sorted(set(wanted) | {r.key for r in record.repositories})
    repositories: dict[str, RepoObserved] = {}
    for key in keys:
        present = layout.repository_dir(key).is_dir()
        head = store.head(key) if present else None
        target = wanted.get(key)
        may_move = target is None or target.commit is None or target.commit != head
        edits = tuple(store.local_edits(key)) if present and may_move else ()
        repositories[key] = RepoObserved(
            key=key, present=present, head=head,
            origin=store.origin_url(key) if present else None, local_edits=edits,
        )
    return Observed(
        record=record,
        repositories=repositories,
        generations=generations.present(layout),
        interrupted=tuple(interrupted_steps(layout)),
        lives=lives(record, services),
        stray_live=_taken_over(layout, record, services),
        deps_by={a.name: d for a in targets.apps
                 for d in [dependencies(layout, a, record, deps)] if d is not None},
        adopt=adoptable(layout, store, record, targets) if record.strays else {},
    )


def lives(record: StateRecord, services: Services | None) -> dict[str, UnitState]:
    """Each installed app's unit now, by app name (none without a manager to ask)."""
    found = {a.name: live_state(a.service, services) for a in record.apps}
    return {name: state for name, state in found.items() if state is not None}


def dependencies(layout: Layout, app: AppTarget, record: StateRecord,
                 ports: DependencyPorts | None) -> DepsObserved | None:
    """The desired app's dependencies as the machine has them now (read-only: dpkg-query,
    distribution metadata, the workspace's build markers), and the ROS commits of the
    installed app of its name."""
    if ports is None:
        return None
    wanted = app.deps
    ros_built = True
    if wanted.ros and wanted.workspace is not None:
        key = wanted.ros_build
        workspace = ports.workspace(Path(wanted.workspace.path), wanted.workspace.user)
        ros_built = key is not None and workspace.built(key)
    now = record.installed(app.name)
    meta = None if now is None else \
        generations.read_meta(layout.generation_meta(now.name, now.generation))
    return DepsObserved(
        apt_missing=tuple(ports.packages.missing(wanted.apt)) if wanted.apt else (),
        pip_unsatisfied=tuple(ports.envs.unsatisfied(wanted.pip)) if wanted.pip else (),
        venv_ready=ports.envs.ready(wanted.pip) if wanted.pip else True,
        ros_built=ros_built, ros_installed=dict(meta.ros) if meta is not None else {},
    )


def _taken_over(layout: Layout, record: StateRecord,
                services: Services | None) -> dict[str, UnitState]:
    """The unit of each app LPAM installed, as its manager says (its `service` file)."""
    found = {s.name: live_state(appdir.service_of(layout.libpanda_apps / s.folder), services)
             for s in record.strays if s.folder is not None and not s.stopped}
    return {name: state for name, state in found.items() if state is not None}


def asks_manager(record: StateRecord) -> bool:
    """Whether observing needs the service manager: only an installed app or an app lpam
    took over has a unit to ask about, so a plan of repositories alone need not load one."""
    return bool(record.apps) or any(
        s.folder is not None and not s.stopped for s in record.strays)


def live_state(unit: str | None, services: Services | None) -> UnitState | None:
    """The app's unit now; None when it names none or no manager is asked."""
    if unit is None or services is None:
        return None
    return services.state(unit)
