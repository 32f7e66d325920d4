"""`lpam status`: the old tool's `-d` table, read from the state record and git objects.

The catalog and the app files (`service`, `description`…) are read from the git objects
of the recorded commit, never from the working tree: a repository may hold a symbolic
link (`service -> /etc/shadow`, or an app folder linking to `/etc`), and a checkout may be
edited, while a blob is exactly what was committed and a link in git is never followed.
It never loads the graph stack, and reads nothing it does not show.

Every installed app is shown (a car may run a controller beside a recorder and a
tracker, issue 22): `--json` keeps `app`, the first installed app, for the readers from
before several apps, and lists every one under `installed`, each with its generation,
its claims and its unit now; the table shows a row per app, and with several apps a line
under it per installed app. A car with one app shows exactly what it showed before.

Whether an app runs is asked of its service manager (the live state), not taken from the
record: the record says what lpam last did, the manager what runs now. Where the manager
cannot know the app's unit, the record's word is shown, marked unverified.

What a repository holds is shown, so it is not trusted: a file too large is left out
rather than failing the whole answer, and the table replaces control characters (a
description could otherwise send escape sequences to the operator's terminal). A
repository whose copy in the store is damaged keeps its row, saying so, and the others
are shown as ever: status must answer most when something is wrong.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from reconciler.base.errors import ConfigError, GitError, StoreDamagedError
from reconciler.base.layout import Layout
from reconciler.base.text import columns, printable
from reconciler.core.documents import parse_catalog
from reconciler.engine.records.state import read_agent_status, read_record
from schemas.catalog import CATALOG_FILE, CatalogApp, with_folder_files

if TYPE_CHECKING:
    from reconciler.base.unit import UnitState
    from schemas.record import AppRecord, StateRecord

SHOWN_FILES = ("description.txt", "service")  # the scripts are not shown, so not read
COLUMNS = ("repository", "ref", "commit", "app", "service", "installed", "running", "status",
           "description")
CELL_LIMIT = 80  # a table cell; the JSON output carries the whole value


class Objects(Protocol):
    """What status needs of the repository store (adapters.git.GitStore): committed blobs."""

    def has_commit(self, key: str, commit: str) -> bool: ...

    def read_file(self, key: str, commit: str, path: str) -> bytes | None: ...

    def damage(self, key: str) -> str | None: ...


@dataclass(frozen=True)
class Row:
    repository: str
    ref: str
    commit: str
    app: str
    service: str
    installed: bool
    running: bool
    status: str | None  # the installed app's lifecycle (schemas.record.AppStatus), else None
    description: str
    verified: bool | None = None  # running asked of the service manager (None: not installed)
    damage: str | None = None  # what is wrong with the repository's copy in the store


def _folder_files(store: Objects, key: str, commit: str, folder: str) -> dict[str, bytes]:
    """The app's descriptive files as committed (regular blobs only: links are not read).
    A file too large to be a description is left out: the rest of the table still shows."""
    files = {}
    for name in SHOWN_FILES:
        try:
            data = store.read_file(key, commit, f"{folder.rstrip('/')}/{name}")
        except GitError:
            continue
        if data is not None:
            files[name] = data
    return files


def _running(installed: AppRecord, live: UnitState | None) -> tuple[bool, bool]:
    """(runs, verified): the manager's answer when it knows the unit, else the record's."""
    if live is not None and live.known:
        return live.running, True
    return installed.running, False


def _app_row(
    store: Objects, common: dict[str, str], app: CatalogApp, installed: AppRecord | None,
    *, key: str, commit: str, live: UnitState | None = None,
) -> Row:
    """One app's row; the installed app's files come from the commit it was installed from."""
    if installed is not None:
        commit, folder = installed.commit, installed.path
    else:
        folder = app.path
    app = with_folder_files(app, _folder_files(store, key, commit, folder))
    runs, verified = _running(installed, live) if installed is not None else (False, None)
    status = None if installed is None else _status(installed, runs)
    service = installed.service if installed is not None and installed.service else None
    return Row(
        repository=common["repository"], ref=common["ref"],
        commit=installed.commit[:12] if installed is not None else common["commit"],
        app=app.name, service=service or app.service or "-",
        installed=installed is not None, running=runs, status=status,
        description=app.description, verified=verified,
    )


def _status(installed: AppRecord, runs: bool) -> str:
    """The lifecycle as a person needs it: what lpam did, and what is still owed."""
    status = installed.status
    if installed.held:
        if runs or status != "installed":
            return f"{status} (an operator's stop did not finish: the next apply stops it)"
        return f"{status} (stopped by operator)"
    if not installed.good:
        return f"{status} (health not proven yet: the next apply checks it)"
    return status


def _note(common: dict[str, str], description: str, damage: str | None = None) -> Row:
    return Row(repository=common["repository"], ref=common["ref"], commit=common["commit"],
               app="-", service="-", installed=False, running=False, status=None,
               description=description, damage=damage)


def _damaged(common: dict[str, str], damage: str) -> Row:
    """The row of a repository whose copy in the store is damaged; the damage itself is
    said in full under the table (a cell holds 80 characters)."""
    return _note(common, "(damaged in the store: the next `lpam apply` fetches it anew)",
                 damage)


def rows(
    layout: Layout, *, record: StateRecord | None = None, store: Objects | None = None,
    lives: Mapping[str, UnitState] | None = None,
) -> list[Row]:
    """Every app of every recorded repository at its recorded commit, and each installed
    app even when no catalog lists it any more (it may be the one that holds the CAN
    hardware). `lives`: each installed app's unit as its manager sees it, by name."""
    if store is None:
        from reconciler.adapters.git import GitStore

        store = GitStore(layout)
    if record is None:
        record = read_record(layout)
    if lives is None:
        lives = {}
    table: list[Row] = []
    for repo in record.repositories:
        common = {"repository": repo.key, "ref": repo.ref or "(default)",
                  "commit": repo.commit[:12]}
        try:
            present = store.has_commit(repo.key, repo.commit)
        except StoreDamagedError as exc:
            table.append(_damaged(common, exc.damage))
            continue
        if not present:  # a lost pack or index hides commits without any read failing
            damage = store.damage(repo.key)
            table.append(_note(common, "(commit missing from the repository store)")
                         if damage is None else _damaged(common, damage))
            continue
        try:
            data = store.read_file(repo.key, repo.commit, CATALOG_FILE)
        except GitError as exc:
            table.append(_note(common, f"(catalog unreadable: {exc.message})"))
            continue
        if data is None:
            table.append(_note(common, "(no libpanda-apps.yaml)"))
            continue
        label = Path(f"{repo.key}@{repo.commit[:12]}/{CATALOG_FILE}")
        try:
            catalog = parse_catalog(label, data.decode("utf-8", "replace"))
        except ConfigError as exc:
            table.append(_note(common, f"(catalog unreadable: {exc.message})"))
            continue
        for app in catalog.apps:
            installed = record.installed(app.name)
            mine = installed if installed is not None and installed.repository == repo.key \
                else None
            table.append(_app_row(store, common, app, mine, key=repo.key,
                                  commit=repo.commit, live=lives.get(app.name)))
    shown = {r.app for r in table if r.installed}
    table += [_unlisted(store, record, a, lives.get(a.name))
              for a in record.apps if a.name not in shown]
    return table


def _unlisted(store: Objects, record: StateRecord, installed: AppRecord,
              live: UnitState | None) -> Row:
    """The installed app when the recorded commit's catalog does not list it (an apply
    that moved the repository was cut off, or the catalog changed)."""
    repo = record.repository(installed.repository)
    common = {"repository": installed.repository,
              "ref": "-" if repo is None else repo.ref or "(default)",
              "commit": installed.commit[:12]}
    app = CatalogApp(name=installed.name, path=installed.path)
    return _app_row(store, common, app, installed, key=installed.repository,
                    commit=installed.commit, live=live)


def _lives(record: StateRecord,
           state: Callable[[str], UnitState] | None) -> dict[str, UnitState]:
    """Each installed app's unit as its manager sees it now, by app name (an app that
    names no unit has none)."""
    if state is None:
        return {}
    return {a.name: state(a.service) for a in record.apps if a.service is not None}


def _app_json(app: AppRecord, live: UnitState | None) -> dict[str, Any]:
    """One installed app as `--json` shows it: what lpam did, what its manager says."""
    runs, verified = _running(app, live)
    return {
        "name": app.name, "repository": app.repository, "commit": app.commit,
        "generation": app.generation, "params": app.params, "running": runs,
        "verified": verified, "status": app.status, "held": app.held,
        "good": app.good,
        "unit": None if live is None else {
            "name": live.name, "known": live.known, "active": live.active,
            "sub": live.sub, "restarts": live.restarts, "pid": live.pid,
            "supervised": live.supervised},
        "command": app.command, "launch": app.launch, "user": app.user,
    }


def _installed_json(record: StateRecord, lives: Mapping[str, UnitState]
                    ) -> list[dict[str, Any]]:
    """Every installed app, in the order they were installed, with what it claims
    (`claims_known` false: recorded before lpam knew claims, taken as the panda's)."""
    return [{**_app_json(a, lives.get(a.name)), "claims": sorted(a.claims),
             "claims_known": a.resources is not None} for a in record.apps]


def as_json(layout: Layout, *, store: Objects | None = None,
            state: Callable[[str], UnitState] | None = None,
            manager: str | None = None) -> dict[str, Any]:
    """`state` asks the service manager (`manager`) about a unit. `app` is the first
    installed app (what readers before several apps read), `installed` every one."""
    record = read_record(layout)  # once: an apply may rewrite it while status runs
    app = record.apps[0] if record.apps else None  # what readers before several apps read
    lives = _lives(record, state)
    last = record.last_apply
    return {
        "app": None if app is None else _app_json(app, lives.get(app.name)),  # the first
        "installed": _installed_json(record, lives),
        "service_manager": manager,
        "last_apply": None if last is None else {**last.model_dump(mode="json"),
                                                 "shown": _last_apply(layout, record)},
        "repositories": [
            {"key": r.key, "url": r.url, "ref": r.ref, "commit": r.commit}
            for r in record.repositories
        ],
        "checkouts_not_running": [  # moved by an apply that did not succeed
            {"key": r.key, "commit": r.commit, "applied_commit": r.applied}
            for r in record.repositories if r.applied != r.commit
        ],
        "holds": holds(record),
        "apps": [asdict(r) for r in rows(layout, record=record, store=store, lives=lives)],
        "strays": [
            {"name": s.name, "generation": s.generation, "stopped": s.stopped,
             "pending": s.pending}
            for s in record.strays
        ],
        "cutover": None if record.cutover is None else record.cutover.model_dump(mode="json"),
        "serial": record.serial,
        "lineage": record.lineage,
        "agent": _agent(layout),
        "override": _override(layout),
        "deferred": _deferred(layout),
    }


def _override(layout: Layout) -> dict[str, Any] | None:
    """The local override in force (reconciler/workflow/override.py); a damaged file is
    reported, not raised: status must always answer."""
    from reconciler.base.errors import LpamError
    from reconciler.engine.records.state import read_override

    try:
        found = read_override(layout)
    except LpamError as exc:
        return {"error": exc.message}
    return None if found is None else found.model_dump(mode="json")


def _deferred(layout: Layout) -> dict[str, str] | None:
    """The last apply, when a closed update gate deferred its cutover (from the journal)."""
    from reconciler.engine.records.journal import deferral

    found = deferral(layout)
    return None if found is None else {"time": found[0], "reason": found[1]}


def _agent(layout: Layout) -> dict[str, Any] | None:
    """What the agent's passes recorded (status.json); None on a machine with no agent.
    A damaged file is reported, not raised: status must always answer."""
    from reconciler.base.errors import LpamError

    try:
        found = read_agent_status(layout)
    except LpamError as exc:
        return {"error": exc.message}
    return None if found is None else found.model_dump(mode="json")


def _cell(value: object) -> str:
    """A value as one printable table cell: no control characters, at most CELL_LIMIT."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if value is None:
        return "-"
    text = printable(str(value))
    return text if len(text) <= CELL_LIMIT else text[: CELL_LIMIT - 3] + "..."


def as_table(layout: Layout, *, store: Objects | None = None,
             state: Callable[[str], UnitState] | None = None,
             manager: str | None = None) -> str:
    record = read_record(layout)
    lives = _lives(record, state)
    table = rows(layout, record=record, store=store, lives=lives)
    strays = [f"Installed without a record: {_cell(s.name)} (generation "
              f"{_cell(s.generation)}); `lpam apply` stops and uninstalls it before "
              "installing any app." for s in record.strays]
    strays += [f"Repository {_cell(r.repository)}: its copy in the store is damaged: "
               f"{printable(r.damage)}; the next `lpam apply` moves it aside and fetches it "
               "anew." for r in table if r.damage is not None]
    strays += _footer(layout, record, lives, manager) + _agent_footer(layout)
    deferred = _deferred(layout)
    if deferred is not None:
        strays.append(f"Cutover deferred at {deferred['time']} (the update gates): "
                      f"{printable(deferred['reason'])}")
    if not table:
        return "\n".join(
            ["No app repositories. Write a desired state and run `lpam apply`.", *strays])
    cells = [[_cell(getattr(r, c)) for c in COLUMNS] for r in table]
    header = [c.capitalize() for c in COLUMNS]
    return "\n".join([*columns(header, cells), *strays])


def _footer(layout: Layout, record: StateRecord, lives: Mapping[str, UnitState],
            manager: str | None) -> list[str]:
    """The lines under the table: each app's unit as its manager sees it (with several
    apps, each app's generation and claims too), checkouts that are not what runs, the
    holds and how each ends, the last apply."""
    lines = []
    if len(record.apps) > 1:
        lines += _apps_footer(record, lives, manager)
    elif record.apps and record.apps[0].name in lives:
        live = lives[record.apps[0].name]
        lines.append(f"Service manager: {manager or '?'}; {printable(_unit_said(live))}")
    lines += [printable(line) for line in _checkouts(record)]
    lines += [printable(f"Held: {h['what']}; it ends {h['ends']}.") for h in holds(record)]
    shown = _last_apply(layout, record)
    if shown is not None:
        lines.append(printable(f"Last apply: {shown}"))
    return lines + _cutover_footer(record)


def _unit_said(live: UnitState) -> str:
    return live.describe() if live.known else \
        f"{live.describe()}: running is what the app's scripts reported (unverified)"


def _apps_footer(record: StateRecord, lives: Mapping[str, UnitState],
                 manager: str | None) -> list[str]:
    """Several apps: one line each, in the order they were installed — its generation,
    its lifecycle, what it claims (what no other app may hold) and its unit now."""
    lines = [f"Installed apps: {len(record.apps)}; service manager: {manager or '?'}"]
    for app in record.apps:
        live = lives.get(app.name)
        runs, _ = _running(app, live)
        claims = ", ".join(sorted(app.claims)) or "nothing exclusive"
        known = "" if app.resources is not None else " (not recorded: taken as the panda's)"
        unit = _unit_said(live) if live is not None else "no unit"
        lines.append(printable(f"  {app.name} (generation {app.generation}): "
                               f"{_status(app, runs)}; claims {claims}{known}; {unit}"))
    return lines


def _checkouts(record: StateRecord) -> list[str]:
    """A checkout only an apply that did not succeed moved is not what runs: said so."""
    lines = []
    for repo in record.repositories:
        if repo.applied == repo.commit:
            continue
        if repo.applied is None:
            lines.append(f"Repository {repo.key}: checked out at {repo.commit[:12]} by an "
                         "apply that did not succeed; nothing that runs comes from it yet.")
        else:
            lines.append(f"Repository {repo.key}: checked out at {repo.commit[:12]} by an "
                         f"apply that did not succeed; what runs came from "
                         f"{repo.applied[:12]}.")
    return lines


def holds(record: StateRecord) -> list[dict[str, str]]:
    """Every hold on this car, what it holds against and how it ends."""
    against = record.desired.source if record.desired is not None else "the desired state"
    found = []
    if record.hold is not None:
        found.append({
            "kind": "rollback", "what": f"`lpam rollback` returned to generation "
            f"{record.hold.name}, and plans propose nothing else",
            "against": against,
            "ends": f"when the desired state last applied ({against}) changes, or with "
            "`lpam apply --release`"})
    start = "`lpam start`" if len(record.apps) <= 1 else "`lpam start {name}`"
    for app in record.apps:  # an operator's stop holds one app
        if app.held:
            found.append({
                "kind": "operator stop", "what": f"{app.name} was stopped by `lpam stop` "
                "and stays stopped", "against": against,
                "ends": f"with {start.format(name=app.name)}, when the desired state last "
                f"applied ({against}) changes, or with `lpam apply --release`"})
    return found


def _last_apply(layout: Layout, record: StateRecord) -> str | None:
    """The last apply as it stands: one `in progress` whose process is gone was cut off
    (a kill, a power cut), and says how to go on."""
    last = record.last_apply
    if last is None:
        return None
    why = f": {last.reason}" if last.reason else ""
    if last.result == "in progress":
        from reconciler.base.process import alive
        from reconciler.engine.execution.lock import holder

        if last.pid is not None and alive(last.pid) and holder(layout) is not None:
            return f"in progress since {last.time} (pid {last.pid})"
        return (f"cut off (began {last.time}; lpam was killed or the power failed): "
                f"`{last.command or 'lpam apply'}` goes on from where it stood")
    again = f"; `{last.command}` goes on from where it stood" \
        if last.result == "interrupted" and last.command else ""
    return f"{last.result} at {last.time}{why}{again}"


def _cutover_footer(record: StateRecord) -> list[str]:
    """An apply a fault cut off mid-cutover, and a rollback it had begun: what the next
    apply owes the car."""
    cutover = record.cutover
    if cutover is None:
        return []
    back = ", ".join(a.name for a in cutover.previous) or "no app"
    rollback = cutover.rollback
    if rollback is not None:
        failed = ", ".join(a.name for a in rollback.failed) or "the new app"
        return [printable(
            f"Rollback cut off: {failed} failed ({rollback.reason}) at {rollback.time}, and "
            f"the rollback to {back} did not finish: the next `lpam apply` finishes it.")]
    return [printable(
        f"Apply cut off mid-cutover (began {cutover.began}): the next `lpam apply` goes on "
        f"from here, and returns to {back} if the new app fails.")]


def _agent_footer(layout: Layout) -> list[str]:
    """The agent's line under the table: which revision runs, which is wanted, the last pass."""
    agent = _agent(layout)
    if agent is None:
        return []
    if "error" in agent:
        return [f"Agent: its status file is unreadable: {printable(agent['error'])}"]

    def short(revision: object) -> str:
        return str(revision)[:12] if revision else "none"

    line = (f"Agent ({_cell(agent['vehicle'])}): applied {short(agent['applied_revision'])}, "
            f"source at {short(agent['desired_revision'])}")
    last = agent.get("last_attempt")
    if last is not None:
        why = f": {last['reason']}" if last.get("reason") else ""
        line += f"; last pass: {last['result']} at {last['time']}{why}"
    lines = [printable(line)]
    override = _override(layout)
    if override is not None and "error" in override:
        lines.append(f"Local override: its file is unreadable: {printable(override['error'])}")
    elif override is not None:
        lines.append(printable(
            f"Local override: the desired state was edited on this car ({override['by']}, "
            f"{override['edits']} edit(s) since {override['since']}); the agent applies it "
            "instead of the fleet's file until `lpam apply --release` or the phone's update "
            "ends it."))
    return lines
