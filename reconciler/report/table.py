"""`lpam status`'s table: the old tool's `-d` columns, a row per app of every recorded
repository, and under it the lines a person needs (each installed app's unit, the holds
and how each ends, the last apply, what a cut-off apply owes the car, and first any of
lpam's files another user may change) — rendered from the status report alone
(schemas/report.py).

A car with one app shows exactly what it showed before several apps; with several, a
line per installed app. What a repository holds is shown, so it is not trusted: the
table replaces control characters (a description could otherwise send escape sequences
to the operator's terminal) and cuts each cell at 80 characters (`--json` has it whole).
"""

from __future__ import annotations

from reconciler.base.text import columns, printable
from schemas.bluetooth import Writes
from schemas.report import InstalledApp, StatusReport, StrayView, UnitView, Unreadable

COLUMNS = ("repository", "ref", "commit", "app", "service", "installed", "running", "status",
           "description")
CELL_LIMIT = 80  # a table cell; the JSON output carries the whole value


def cell(value: object) -> str:
    """A value as one printable table cell: no control characters, at most CELL_LIMIT."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if value is None:
        return "-"
    text = printable(str(value))
    return text if len(text) <= CELL_LIMIT else text[: CELL_LIMIT - 3] + "..."


def render(report: StatusReport) -> str:
    lines = [printable(f"Unsafe: {e.said}.") for e in report.exposed]  # first: most urgent
    lines += [_stray(s) for s in report.strays]
    lines += [f"Repository {cell(r.repository)}: its copy in the store is damaged: "
              f"{printable(r.damage)}; the next `lpam apply` moves it aside and fetches it "
              "anew." for r in report.apps if r.damage is not None]
    lines += _footer(report) + _agent(report) + _bluetooth(report)
    if not report.apps:
        return "\n".join(
            ["No app repositories. Write a desired state and run `lpam apply`.", *lines])
    # the Status column says the status word and what is owed (`said`), not the record's
    # bare lifecycle: `running` there beside Running `no` was a contradiction
    shown = {"status": "said"}
    cells = [[cell(getattr(r, shown.get(c, c))) for c in COLUMNS] for r in report.apps]
    header = [c.capitalize() for c in COLUMNS]
    return "\n".join([*columns(header, cells), *lines])


def _stray(stray: StrayView) -> str:
    """An app installed without a record, and what `lpam apply` does with it: what the
    plan does (the report's `fate`, from the same observation)."""
    if stray.fate == "adopted":
        return (f"Installed by LPAM: {cell(stray.name)}, the desired app "
                f"{cell(stray.adopted_as)} as it is: `lpam apply` adopts it in place (no "
                "script runs, it is not restarted).")
    if stray.fate == "known after fetch":
        return (f"Installed by LPAM: {cell(stray.name)}; whether `lpam apply` adopts it in "
                "place or stops and uninstalls it is known once `lpam plan` has fetched the "
                "desired commits.")
    return (f"Installed without a record: {cell(stray.name)} (generation "
            f"{cell(stray.generation)}); `lpam apply` stops and uninstalls it before "
            "installing any app.")


def unit_said(unit: UnitView) -> str:
    """The unit as its manager answered; one it cannot know leaves the status unverified
    (whatever that status is: a stopped app's scripts reported no running)."""
    return unit.said if unit.known else \
        f"{unit.said}: the status is lpam's record, unverified"


def _footer(report: StatusReport) -> list[str]:
    """Each app's unit as its manager sees it (with several apps, each app's generation
    and claims too), checkouts that are not what runs, the holds, the last apply."""
    lines = []
    manager = report.service_manager or "?"
    if len(report.installed) > 1:
        lines.append(f"Installed apps: {len(report.installed)}; service manager: {manager}")
        lines += [printable(_app_line(app)) for app in report.installed]
    elif report.app is not None and report.app.unit is not None:
        lines.append(f"Service manager: {manager}; {printable(unit_said(report.app.unit))}")
    for repo in report.checkouts_not_running:  # moved by an apply that did not succeed
        runs = "nothing that runs comes from it yet." if repo.applied_commit is None else \
            f"what runs came from {repo.applied_commit[:12]}."
        lines.append(printable(f"Repository {repo.key}: checked out at {repo.commit[:12]} "
                               f"by an apply that did not succeed; {runs}"))
    lines += [printable(f"Held: {h.what}; it ends {h.ends}.") for h in report.holds]
    if report.last_apply is not None:
        by = report.last_apply.by  # who asked for it (issue 31), when the record says
        lines.append(printable(f"Last apply: {report.last_apply.shown}"
                               + (f" (asked by {by.shown})" if by is not None else "")))
    return lines + _cutover(report)


def _app_line(app: InstalledApp) -> str:
    """One installed app: its generation, its lifecycle, what it claims (what no other
    app may hold) and its unit now."""
    claims = ", ".join(app.claims) or "nothing exclusive"
    known = "" if app.claims_known else " (not recorded: taken as the panda's)"
    unit = "no unit" if app.unit is None else unit_said(app.unit)
    return (f"  {app.name} (generation {app.generation}): {app.said}; claims {claims}"
            f"{known}; {unit}")


def _cutover(report: StatusReport) -> list[str]:
    """The cutover the record keeps, said from the last apply's one state: the live
    apply's own while it runs (never "cut off" beside "in progress"); otherwise what a
    fault, a Ctrl-C or a failure left, which the next apply owes the car."""
    cutover = report.cutover
    if cutover is None:
        return []
    back = ", ".join(a.name for a in cutover.previous) or "no app"
    state = report.last_apply.state if report.last_apply is not None else "cut off"
    rollback = cutover.rollback
    if state == "in progress":
        if rollback is not None:
            return [printable(f"Rolling back to {back} since {rollback.time}: "
                              f"{rollback.reason}.")]
        return [printable(f"Cutover under way since {cutover.began}: it returns to {back} "
                          "if the new app fails.")]
    ended = {"cut off": "cut off", "interrupted": "interrupted"}.get(state, "left unfinished")
    last = report.last_apply
    again = f"`{last.command}`" if last is not None and last.command else "the next `lpam apply`"
    if rollback is not None:
        failed = ", ".join(a.name for a in rollback.failed) or "the new app"
        return [printable(
            f"Rollback {ended}: {failed} failed ({rollback.reason}) at {rollback.time}, "
            f"and the rollback to {back} did not finish: {again} finishes it.")]
    return [printable(
        f"Apply {ended} mid-cutover (began {cutover.began}): {again} goes on from here, "
        f"and returns to {back} if the new app fails.")]


def _agent(report: StatusReport) -> list[str]:
    """The agent's line: which revision runs, which is wanted, the last pass; and a local
    override in force."""
    agent = report.agent
    if agent is None:
        return []
    if isinstance(agent, Unreadable):
        return [f"Agent: its status file is unreadable: {printable(agent.error)}"]

    def short(revision: str | None) -> str:
        return revision[:12] if revision else "none"

    line = (f"Agent ({cell(agent.vehicle)}): applied {short(agent.applied_revision)}, "
            f"source at {short(agent.desired_revision)}")
    last = agent.last_attempt
    if last is not None:
        why = f": {last.reason}" if last.reason else ""
        line += f"; last pass: {last.result} at {last.time}{why}"
    lines = [printable(line)]
    wave = agent.rollout
    if wave is not None:  # the waves of the fleet's rollout (issue 34): where this car stands
        place = f"wave {wave.wave}" if wave.wave is not None else "in no wave"
        lines.append(printable(
            f"Rollout of {short(wave.revision)}: {place}, {wave.stage} since {wave.since}"
            + (f": {wave.reason}" if wave.reason else "")))
    local = report.override
    if isinstance(local, Unreadable):
        lines.append(f"Local override: its file is unreadable: {printable(local.error)}")
    elif local is not None:
        lines.append(printable(
            f"Local override: the desired state was edited on this car ({local.by}, "
            f"{local.edits} edit(s) since {local.since}); the agent applies it instead of "
            "the fleet's file until `lpam apply --release` or the phone's update ends it."))
    return lines


def _bluetooth(report: StatusReport) -> list[str]:
    """Who may change the car over Bluetooth, while `lpam ble` runs (else nothing: no
    phone can change anything then)."""
    ble = report.bluetooth
    if ble is None:
        return []
    if ble.writes is Writes.OPEN:
        return [printable(f"Bluetooth (lpam ble on {ble.adapter}): writes are OPEN: any phone "
                          "in range may change the car's apps (--writes open)")]
    return [printable(f"Bluetooth (lpam ble on {ble.adapter}): only a bonded phone may change "
                      "the car's apps; `lpam ble pair` lets a phone pair")]
