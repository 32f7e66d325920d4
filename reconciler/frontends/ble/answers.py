"""What the phone's requests do: each one the same workflow function a command runs.

The phone edits the desired state (workflow/editing.py) and asks for what the operator
commands do (workflow/operate.py); nothing here decides a rule — locks, gates, holds and
validation are the workflow's — and nothing here ever builds a shell string. Every answer
is a status text the phone shows (the success texts exactly the phone's, because it
refreshes its app list on them; a failure names its reason and never reads as success)
and, for reads, a message on the output characteristic.

The phone waits for no apply: an apply already running is an error text at once
(`PHONE_LOCK_WAIT`), not a hang.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from reconciler.base.errors import ConfigError, LpamError
from reconciler.core.privzone import messages as m
from reconciler.workflow.applying import ApplyOptions
from reconciler.workflow.events import Report
from reconciler.workflow.machine import Machine
from schemas.plan import Plan
from schemas.record import Actor
from schemas.report import StatusReport, Unreadable

# Imported inside functions: each phone request loads only its own use case (operate: ~60
# modules); the others add 0-2 modules once this module is loaded (small start-up gain).

PHONE_LOCK_WAIT = 2.0
"""Seconds a phone's request waits for another apply (the agent's, a terminal's)."""

BY = "phone"
"""Who a phone's edit is recorded as (a local override on a fleet car)."""

MAX_REASON = 300
"""Characters of a failure's reason sent to the phone (a status text is one line)."""


@dataclass(frozen=True)
class Answer:
    """A status text for the status characteristic (None: none) and notifications for
    the output characteristic, sent in order about 50 ms apart."""

    status: str | None = None
    output: Sequence[bytes] = field(default_factory=tuple)


def options(by: Actor) -> ApplyOptions:
    """A phone's apply: the defaults of `lpam apply`, but no long wait for the lock; `by`:
    the phone that asked (recorded with what it changes)."""
    return ApplyOptions(lock_timeout=PHONE_LOCK_WAIT, resume="lpam apply", by=by)


def reason(exc: LpamError) -> str:
    """A failure as one short line: the document's file:line:col where there is one."""
    text = f"{exc.where}: {exc.message}" if isinstance(exc, ConfigError) else exc.message
    text = " ".join(text.split())
    return text if len(text) <= MAX_REASON else text[: MAX_REASON - 1] + "…"


def command(machine: Machine, given: m.Command, report: Report, *, by: Actor) -> Answer:
    """A command written to the command (or config) characteristic by the phone `by`."""
    from reconciler.workflow.operate import operate_installed

    if given is m.Command.INFO:
        return Answer(output=app_info(machine))
    action = given.action
    if action is None:
        return Answer(status=m.Status.not_served("this command"))
    failed = m.Failure.STOPPING if given is m.Command.STOP else m.Failure.RESTARTING
    try:
        operate_installed(machine, action, file=None, force=False, options=options(by),
                          report=report)
    except LpamError as exc:
        return Answer(status=failed.because(reason(exc)))
    return Answer(status=m.Status.APP_COMMAND_SUCCESS)


def app_info(machine: Machine) -> list[bytes]:
    """`A`: every app of every repository, as `libpanda-app-manager -d` lists them: each
    installed app `enabled` (several run side by side: workflow/inventory.py)."""
    from reconciler.workflow.inventory import report

    return m.app_info_message(report(machine).listed())


def request(machine: Machine, given: m.Request, report: Report, *, by: Actor) -> Answer:
    """A message written to the input characteristic by the phone `by`, already parsed
    and checked."""
    from reconciler.workflow import editing

    try:
        if isinstance(given, m.AppEnable):
            editing.enable_app(machine, given.app, options=options(by), report=report, by=BY)
            return Answer(status=m.Status.APP_COMMAND_SUCCESS)
        if isinstance(given, m.AppUpdate):
            editing.update(machine, options=options(by), report=report)
            return Answer(status=m.Status.APP_UPDATED)
        if isinstance(given, m.AddRepository):
            editing.add_repository(machine, given.repository, given.branch,
                                   options=options(by), report=report, by=BY)
            return Answer(status=m.Status.REPOSITORY_UPDATED)
        if isinstance(given, m.RemoveRepository):
            editing.remove_repository(machine, given.repository, options=options(by),
                                      report=report, by=BY)
            return Answer(status=m.Status.REPOSITORY_REMOVED)
        if isinstance(given, m.AppParams):
            editing.set_params(machine, given.app, dict(given.params), options=options(by),
                               report=report, by=BY)
            return Answer(status=m.Status.APP_COMMAND_SUCCESS)
        if isinstance(given, m.ReadSummary):
            return Answer(output=m.summary_message(summary(machine)))
        return Answer(status=m.Status.not_served(str(given.kind)))
    except LpamError as exc:
        return Answer(status=failure(given, reason(exc)))


def failure(given: m.Request, why: str) -> str:
    """The phone's error text for a request that failed, with the reason."""
    if isinstance(given, m.AppEnable):
        return m.Status.enabling_failed(given.app, why)
    found = {m.AppUpdate: m.Failure.UPDATING, m.AddRepository: m.Failure.ADDING,
             m.RemoveRepository: m.Failure.REMOVING, m.AppParams: m.Failure.PARAMS,
             m.ReadSummary: m.Failure.SUMMARY}.get(type(given))
    return found.because(why) if found is not None else f"Error: {why}"


def summary(machine: Machine) -> dict[str, str]:
    """lpam's extra read: the app as it stands (`app` … `running`: the first installed;
    `apps`: every installed app and its status, when several run), what an apply would
    do now (planned with
    no network, from what the last fetch brought), the revisions the agent applied and
    wants, a local override, and the update gates now (of the desired state in force:
    workflow/gates.py). A part that cannot be known says why; the read never fails."""
    from reconciler.report import status

    plan, gates = _plan_and_gates(machine)
    return summary_of(status.report(machine.layout, state=machine.services.state,
                                    plan=plan, gates=gates, listed=False))


def summary_of(shown: StatusReport) -> dict[str, str]:
    """The summary, rendered from the status report."""
    app, agent, local = shown.app, shown.agent, shown.override
    agent = None if isinstance(agent, Unreadable) else agent
    return {
        "app": "None" if app is None else app.name,
        "generation": "" if app is None else app.generation,
        "status": "" if app is None else app.standing,
        "running": "yes" if app is not None and app.running else "no",
        "apps": ", ".join(f"{a.name} {a.standing}" for a in shown.installed) or "None",
        "applied_revision": "" if agent is None else agent.applied_revision or "",
        "desired_revision": "" if agent is None else agent.desired_revision or "",
        "override": "none" if local is None else "? since ?"
        if isinstance(local, Unreadable) else f"{local.by} since {local.since}",
        "plan": "" if shown.plan is None else shown.plan.summary, "gates": shown.gates or "",
    }


def _plan_and_gates(machine: Machine) -> tuple[Plan | str, str]:
    """What an apply would do now, offline (or why it is not known), and the update
    gates now."""
    from reconciler.workflow.events import Event
    from reconciler.workflow.gates import in_force
    from reconciler.workflow.planning import plan

    def quiet(event: Event) -> None:
        return None

    try:
        wanted = in_force(machine, None)
    except LpamError as exc:
        return f"not known: {reason(exc)}", "not known"
    if wanted is None:
        return "no desired state on this car", "none"
    made: Plan | str
    try:
        made = plan(machine, wanted.label, wanted.desired, report=quiet, offline=True,
                    lock_timeout=PHONE_LOCK_WAIT, places=wanted.places)
    except LpamError as exc:
        made = f"not known: {reason(exc)}"
    try:
        gate = machine.gate_for(wanted.desired, wanted.base_dir)
        gates = "none" if gate is None else "; ".join(g.describe() for g in gate.states())
    except LpamError as exc:
        gates = f"not known: {reason(exc)}"
    return made, gates
