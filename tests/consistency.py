"""What lpam says, checked against itself and against the car (issue 30, "What to build" 3):
the four checks of tests/reliability/test_consistency.py, written once for its two layers
(the in-process one on in-memory twins, the real one on subprocesses and supervisord).

Each check takes what a user reads — `lpam status --json` (the StatusReport, with `app`),
the table `lpam status` prints, the plan `lpam plan --json` prints and its rendering, and
every line a command printed — and returns the violations it finds, each a sentence that
names what contradicts what. None raises: a round collects every violation, so that one
failure shows all that is wrong at that moment.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from schemas.plan import Plan

IN_PROGRESS = re.compile(r"\bin progress\b", re.IGNORECASE)
CUT_OFF = re.compile(r"\bcut off\b", re.IGNORECASE)
OWED = ("goes on from where it stood", "the next `lpam apply`", "the next apply")
"""Words by which the report says something is still owed to the car."""
MATCHES = "matches the desired state"
HINT = re.compile(r"`(lpam [^`]*)`")
PLACEHOLDER = re.compile(r"\b(APP|FILE|PLANFILE|N|SECONDS|ROOT|URL|PATH)\b|[.][.][.]|…")
PATH_OPTIONS = ("-f", "--file", "--config", "-o", "--out", "--output", "--bundle")
COMMANDS_WITH_PLANFILE = ("apply",)


def both_in_progress_and_cut_off(report: dict[str, Any], table: str) -> list[str]:
    """(a) The report never says the last apply is in progress and that it was cut off."""
    found = []
    last = report.get("last_apply") or {}
    shown = last.get("shown") or ""
    if IN_PROGRESS.search(shown) and CUT_OFF.search(shown):
        found.append(f"(a) last_apply.shown says in progress and cut off: {shown!r}")
    if IN_PROGRESS.search(table) and CUT_OFF.search(table):
        lines = [line for line in table.splitlines()
                 if IN_PROGRESS.search(line) or CUT_OFF.search(line)]
        found.append(f"(a) the table says in progress and cut off: {lines}")
    return found


def last_apply_as_it_ended(report: dict[str, Any], table: str, command: str,
                           code: int | str) -> list[str]:
    """(a), after an apply whose end the user saw: the report's word for the last apply is
    how it ended — deferred by the gates (75) is not killed nor cut off; interrupted
    (130, 143) is not cut off; one that lpam saw end is not in progress."""
    if command != "apply":
        return []
    shown = (report.get("last_apply") or {}).get("shown") or ""
    cut = [line for line in table.splitlines() if CUT_OFF.search(line)]
    found = []
    if code == 75 and (cut or "killed" in shown):
        found.append(f"(a) the apply was deferred (exit 75); the table says {cut}")
    if code in (130, 143) and cut:
        found.append(f"(a) the apply was interrupted (exit {code}); the table says {cut}")
    if isinstance(code, int) and code not in (-9, -2, -15) and IN_PROGRESS.search(shown):
        found.append(f"(a) the apply ended (exit {code}); the report says {shown!r}")
    return found


def owed(report: dict[str, Any]) -> list[str]:
    """What the report says the car is still owed (an apply has work to do), in its words;
    the holds are not owed (they hold the car where it is)."""
    found = []
    last = report.get("last_apply") or {}
    shown = last.get("shown") or ""
    if any(word in shown for word in OWED) or CUT_OFF.search(shown):
        found.append(f"last apply: {shown}")
    if report.get("deferred") is not None:
        found.append(f"deferred: {report['deferred'].get('reason')}")
    if report.get("cutover") is not None:
        found.append("a cutover cut off")
    found += [f"stray {s['name']}" for s in report.get("strays") or []]
    for app in report.get("installed") or []:
        said = app.get("said") or ""
        if any(word in said for word in OWED):
            found.append(f"{app['name']}: {said}")
        elif app.get("held"):
            continue
        elif app.get("status") != "running":
            found.append(f"{app['name']}: {app.get('status')} (not held)")
        elif not app.get("running"):
            found.append(f"{app['name']}: status running, not running by "
                         f"{'its manager' if app.get('verified') else 'the record'}")
    return found


def differs(report: dict[str, Any]) -> list[str]:
    """What in the report tells a reader the car is not (yet) the desired state: what is
    owed, and a last apply that failed or was rolled back."""
    last = report.get("last_apply") or {}
    found = owed(report)
    if last.get("result") in ("failed", "rolled back", "interrupted", "in progress"):
        found.append(f"last apply {last.get('result')}")
    return found


def proposed(made: Plan) -> list[str]:
    """What a plan proposes: its steps, or with none the changes it still makes — an apply
    with nothing to run that ends what an earlier apply left owed writes the record
    (reconciler/core/planning/settling.py)."""
    from schemas.plan import Action

    return [s.id for s in made.steps] or \
        [c.address for c in made.changes if c.action is not Action.NOOP]


def plan_agrees(report: dict[str, Any], table: str, steps: Sequence[str],
                plan_text: str) -> list[str]:
    """(b) `plan` proposes nothing (`proposed`) ⇔ the report shows nothing pending except
    holds, which it names (the table too), and then the plan does not say the machine
    matches."""
    found = []
    if not steps and owed(report):
        found.append(f"(b) plan proposes nothing, but the report says owed: {owed(report)}")
    if steps and not differs(report):
        found.append(f"(b) plan proposes {list(steps)}, but the report shows nothing "
                     "pending")
    named = {h.get("what", "") for h in report.get("holds") or []}
    for app in report.get("installed") or []:
        if app.get("held") and not any(app["name"] in what for what in named):
            found.append(f"(b) {app['name']} is held (operator stop), and no hold names it")
    if report.get("holds") and "Held:" not in table:
        found.append("(b) the JSON has holds, the table names none")
    held = [a["name"] for a in report.get("installed") or [] if a.get("held")]
    rollback = [h for h in report.get("holds") or [] if h.get("kind") == "rollback"]
    if (held or rollback) and MATCHES in plan_text:
        found.append(f"(b) under holds ({held or 'rollback'}) the plan says "
                     f"{last_line(plan_text)!r}")
    return found


def last_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else ""


def running_is_true(report: dict[str, Any], table: str,
                    manager_runs: dict[str, bool | None]) -> list[str]:
    """(c) Every app the report calls running is running by the service manager's word
    (`manager_runs`: app → its unit runs; None: the app has no unit the manager knows), or
    is marked unverified where it is shown; and no face calls it running while another
    face, or another column, says it is not."""
    found = []
    rows = table_rows(table)
    for app in report.get("installed") or []:
        name = app["name"]
        live = manager_runs.get(name)
        if app.get("running") and live is False:
            found.append(f"(c) the report says {name} runs; its service manager says not")
        if app.get("running") and live is None and app.get("verified"):
            found.append(f"(c) {name} is called running and verified; its manager knows "
                         "no unit of it")
        if app.get("running") and not app.get("verified") and \
                not unverified_shown(table, name, len(report.get("installed") or [])):
            found.append(f"(c) the table shows {name} running, and nowhere that this is "
                         "unverified (its JSON says verified: false)")
        if not app.get("running") and "running is what the app's scripts reported" in \
                app_lines(table, name, len(report.get("installed") or [])):
            found.append(f"(c) {name} is not running, yet the table says running is what "
                         "its scripts reported")
        row = rows.get(name)
        if row is not None:
            shown_runs = row.get("Running") == "yes"
            if shown_runs != bool(app.get("running")):
                found.append(f"(c) {name}: the table's Running says {row.get('Running')}, "
                             f"the JSON running={app.get('running')}")
            status = row.get("Status", "")
            if row.get("Running") == "no" and status.split(" ")[0] == "running":
                found.append(f"(c) {name}: `Running no` beside `Status {status}`")
    return found


def app_lines(table: str, name: str, count: int) -> str:
    """The lines of the table that speak of installed app `name` (one app: every line
    below the columns)."""
    lines = table.splitlines()
    if count <= 1:
        return "\n".join(line for line in lines if not line.startswith(("Repository ",)))
    return "\n".join(line for line in lines if line.startswith(f"  {name} ")
                     or f" {name} " in line)


def unverified_shown(table: str, name: str, count: int) -> bool:
    return "unverified" in app_lines(table, name, count)


def table_rows(table: str) -> dict[str, dict[str, str]]:
    """App → its row in the table's columns (cut at the header's column starts)."""
    lines = table.splitlines()
    header = next((i for i, line in enumerate(lines)
                   if line.startswith("Repository") and "Running" in line), None)
    if header is None:
        return {}
    head = lines[header]
    names = head.split()
    starts = [head.index(n) for n in names]
    rows: dict[str, dict[str, str]] = {}
    for line in lines[header + 1:]:
        if not line.strip() or (line.startswith(("-", "=")) and set(line.strip()) <= {"-", "="}):
            continue
        if len(line) < starts[-1]:
            break
        cells = {}
        for i, n in enumerate(names):
            end = starts[i + 1] if i + 1 < len(names) else None
            cells[n] = line[starts[i]:end].strip()
        if cells.get("App") and cells.get("Installed") in ("yes", "no"):
            rows.setdefault(cells["App"], cells)
    return rows


@dataclass(frozen=True)
class Hint:
    """A command lpam suggested, as printed, and where it was printed."""

    text: str
    where: str

    @property
    def argv(self) -> list[str] | None:
        try:
            return shlex.split(self.text)
        except ValueError:
            return None


def hints(texts: Iterable[tuple[str, str]]) -> list[Hint]:
    """Every command in backquotes that lpam printed (`where`: which output), save the
    templates that name a placeholder (`lpam start APP`)."""
    found: dict[str, Hint] = {}
    for where, text in texts:
        for match in HINT.finditer(text):
            command = match.group(1).strip()
            before = text[max(0, match.start() - 4):match.start()]
            after = text[match.end():match.end() + 9]
            if PLACEHOLDER.search(command) or before.endswith("by ") or \
                    after.startswith(" returned"):
                continue  # a template, or a past command named ("stopped by `lpam stop`")
            found.setdefault(command, Hint(command, where))
    return list(found.values())


def hint_as_printed(hint: Hint, root: Path) -> list[str]:
    """(d), the part that needs no run: a suggested command runs as printed from another
    directory only if it names the root it was given (`--root`: else it acts on /, or on
    $LPAM_ROOT) and every file it names by an absolute path."""
    argv = hint.argv
    if argv is None:
        return [f"(d) `{hint.text}` ({hint.where}) is not a command a shell can split"]
    found = []
    args = argv[1:]
    if "--root" not in args or args[args.index("--root") + 1:][:1] != [str(root)]:
        found.append(f"(d) `{hint.text}` ({hint.where}) does not name --root {root}: "
                     "run as printed from another directory it acts on another car")
    for i, arg in enumerate(args):
        value = None
        if arg in PATH_OPTIONS and i + 1 < len(args):
            value = args[i + 1]
        elif any(arg.startswith(o + "=") for o in PATH_OPTIONS if o.startswith("--")):
            value = arg.split("=", 1)[1]
        if value is not None and not Path(value).is_absolute():
            found.append(f"(d) `{hint.text}` ({hint.where}) names {value!r} relative to "
                         "the directory it was typed in")
    return found


def failed_as_printed(hint: Hint, code: int, err: str) -> list[str]:
    """(d), the run: a suggested command, run from another directory, is understood (not a
    usage error) and finds every file it names."""
    if code == 2 and "usage:" in err:
        return [f"(d) `{hint.text}` ({hint.where}) is refused by the parser: "
                f"{last_line(err)}"]
    if re.search(r"(No such file|does not exist|not found: .*\.ya?ml|cannot read)", err):
        return [f"(d) `{hint.text}` ({hint.where}) cannot find what it names: "
                f"{last_line(err)}"]
    if "internal error" in err or "Traceback" in err:
        return [f"(d) `{hint.text}` ({hint.where}) ends in an internal error: "
                f"{last_line(err)}"]
    return []
