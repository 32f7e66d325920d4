"""The logs use case: what the installed apps printed, from wherever that is known.

A scriptless app's unit, and a script app's unit that the service manager knows, have
their output in the manager (supervisord's log file, systemd's journal). A script app
whose unit the manager cannot know (the field's apps name systemd units; under
supervisord those are not its own) still printed something lpam saw: its scripts' output
during lpam's applies, in the run logs (`<root>/var/log/lpam/<command>-<time>-<pid>.log`,
each script's output under a `== APP: bash SCRIPT (in DIR)` line). That is shown, with a
plain word on where the unit's own output is. Nothing known at all is an error naming
where to look — never an empty answer with exit 0.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import LpamError
from reconciler.base.layout import Layout
from reconciler.engine.records.state import read_record
from reconciler.workflow.applying import installed_apps
from reconciler.workflow.machine import Machine

if TYPE_CHECKING:
    from schemas.record import AppRecord

LOG_FILES = 50  # run logs looked at, newest first: enough for weeks of applies
READ_LIMIT = 1024 * 1024  # bytes of one run log
FOLLOW_LINES = 200  # asked of the manager each second while following


@dataclass(frozen=True)
class Shown:
    """Lines to print, notes to say beside them, and what `-f` can follow: one app's unit
    (`unit`), or with several apps each app's unit, by app name (`units`, whose lines
    are prefixed with the app's name as `lines` are)."""

    lines: list[str]
    notes: list[str] = field(default_factory=list)
    unit: str | None = None  # the unit to follow, when its manager has its output
    units: dict[str, str] = field(default_factory=dict)
    seen: dict[str, list[str]] = field(default_factory=dict)  # each unit's lines shown


def app_logs(machine: Machine, lines: int, app: str | None = None) -> Shown:
    """The last `lines` lines of output of the installed app `app`, or with no name, of
    the only installed app — or of every installed app when there are several: `lpam
    logs` then shows each app's last lines in turn (the order they were installed), each
    line prefixed with `APP | ` as `docker compose logs` does, which is what a user who
    typed no name expects; notes name the app too. An unknown name is refused, naming
    the installed apps."""
    chosen = installed_apps(read_record(machine.layout), app, "there is no output to show")
    if len(chosen) == 1:
        return logs_of(machine, chosen[0], lines)
    return _every_app(machine, chosen, lines)


def _every_app(machine: Machine, installed: list[AppRecord], lines: int) -> Shown:
    """Each app's output in turn, prefixed with its name; an app with none known is a note,
    not a failure of the others' (unless no app has any)."""
    said: list[str] = []
    notes: list[str] = []
    units: dict[str, str] = {}
    seen: dict[str, list[str]] = {}
    errors: list[str] = []
    for app in installed:
        try:
            shown = logs_of(machine, app, lines)
        except LpamError as exc:
            errors.append(exc.message)
            continue
        said += [f"{app.name} | {line}" for line in shown.lines]
        notes += [f"{app.name}: {note}" for note in shown.notes]
        if shown.unit is not None:
            units[app.name] = shown.unit
            seen[app.name] = shown.lines
    if not said and not units:
        raise LpamError(f"no output of any installed app is known to lpam: {'; '.join(errors)}",
                        hint=f"their scripts' output would be in {machine.layout.logs}/*.log")
    return Shown(said, notes + errors, units=units, seen=seen)


def logs_of(machine: Machine, app: AppRecord, lines: int) -> Shown:
    """One installed app's last `lines` lines of output."""
    if app.service is not None:
        state = machine.services.state(app.service)
        if state.known:
            said = machine.services.logs(app.service, lines)
            notes = [] if said else [f"unit {app.service} has printed nothing yet"]
            return Shown(said, notes, unit=app.service)
    scripts = script_output(machine.layout, app.name, lines)
    where = (f"unit {app.service} is not known to {machine.services.kind}: its own output is "
             f"where it writes (on a vehicle with systemd: `journalctl -u {app.service}`)"
             if app.service is not None else f"{app.name} names no unit (no `service` file)")
    if not scripts:
        raise LpamError(f"no output of {app.name} is known to lpam: {where}",
                        hint=f"its scripts' output would be in {machine.layout.logs}/*.log")
    return Shown(scripts, [f"{where}; below, what its scripts printed during lpam's runs"])


def new_output(machine: Machine, shown: Shown, *,
               sleep: Callable[[float], None] = time.sleep) -> Iterator[str]:
    """`lpam logs -f`: the lines the app prints after `shown`, as they come, forever; only
    a unit whose manager has its output can be followed. With several apps, each app's
    unit is asked in turn each second, and its new lines prefixed with its name."""
    if shown.unit is None and not shown.units:
        raise LpamError("cannot follow: the service manager does not have this app's output",
                        hint="the note above says where it is")
    if shown.unit is not None:
        units, previous = {"": shown.unit}, {"": shown.lines}
    else:
        units, previous = dict(shown.units), {n: list(v) for n, v in shown.seen.items()}
    while True:
        sleep(1.0)
        for name, unit in units.items():
            lines = machine.services.logs(unit, FOLLOW_LINES)
            fresh = lines[seen_up_to(previous.get(name, []), lines):]
            yield from (f"{name} | {line}" for line in fresh) if name else fresh
            previous[name] = lines


def seen_up_to(before: list[str], after: list[str]) -> int:
    """Where the lines of `after` that -f has not printed yet begin: just past the latest
    place where `after` holds the end of `before`. `before` may be a shorter window than
    `after` (`-n N` showed N lines; following asks for FOLLOW_LINES), so the N lines are
    looked for inside `after`, not only at its start: else the whole window is printed
    again. None of `before` in `after` (the log was rotated): every line is new."""
    for end in range(len(after), 0, -1):
        size = min(len(before), end)
        if size and after[end - size:end] == before[-size:]:
            return end
    return 0


def script_output(layout: Layout, app: str, lines: int) -> list[str]:
    """The last `lines` lines the app's scripts printed in lpam's run logs, oldest first,
    each script's part under its `== ` line and the run it came from."""
    found: list[str] = []
    for log in _newest_first(layout.logs):
        part = list(_sections(log, app))
        found = part + found
        if len(found) >= lines:
            break
    return found[-lines:] if lines > 0 else []


def _newest_first(folder: Path) -> list[Path]:
    try:
        logs = [p for p in folder.glob("*.log") if p.is_file() and not p.is_symlink()]
    except OSError:
        return []
    # `<command>-<YYYYmmddTHHMMSSZ>-<pid>.log`: the time sorts them
    logs.sort(key=lambda p: (p.name.split("-")[1:2], p.name), reverse=True)
    return logs[:LOG_FILES]


def _sections(log: Path, app: str) -> Iterator[str]:
    """The lines of `log` under the headers of `app`'s scripts (header included)."""
    try:
        with open(log, "rb") as handle:
            handle.seek(0, 2)
            size = handle.tell()
            handle.seek(max(size - READ_LIMIT, 0))
            text = handle.read().decode("utf-8", "replace")
    except OSError:
        return
    mine = False
    header = f"== {app}: "
    run = log.name.removesuffix(".log")
    for line in text.splitlines():
        if line.startswith("== "):
            mine = line.startswith(header)
            if mine:
                yield f"{line}  [{run}]"
            continue
        if mine:
            yield line
