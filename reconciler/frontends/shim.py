"""`libpanda-app-manager`: LPAM's command line, kept for the scripts and habits that call
it, acting through lpam.

It parses LPAM's flags exactly as its `getopts ":htkdscupli:g:b:r:"` did (clustered flags
`-dc`, a value joined `-iAPP` or apart `-i APP`, `-g` acted on after the others), then each
flag calls one workflow function — the same ones the Bluetooth service calls — so every
rule (lock, gates, validation, health check) is lpam's. Unlike LPAM, it tells the truth:
exit 0 only on success, each error one line on stderr, a value that looks like an option
(`-i --upload-pack=x`) refused as a usage error, and no shell anywhere. LPAM's interactive
menu (no flags) is gone: the usage is printed instead (on stderr, with exit 2: nothing
was done, as for any usage error), so that whoever typed the bare name learns the flags.

A car may run several apps side by side (issue 22): `-d` says `yes` under Enabled for each
installed app and `-c` prints each on its own line, as LPAM printed its one; `-i APP`
replaces only the apps that claim a resource APP claims (workflow/editing.py).

`-d` prints LPAM's table for bluezone, which decodes it as UTF-8, then latin-1 through
Python's `unicode_escape`: so the table is ASCII, non-ASCII text written as the `\\xNN`
escapes of its UTF-8 bytes (bluezone turns them back into the characters) and a backslash
doubled; a tab or line break inside a value would split bluezone's columns or rows and is
written as a space.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import LpamError
from reconciler.base.modes import keep_writes_private
from reconciler.base.text import counted

if TYPE_CHECKING:
    from reconciler.base.layout import Layout
    from reconciler.workflow.applying import ApplyOptions
    from reconciler.workflow.events import Report
    from reconciler.workflow.machine import Machine
    from schemas.report import CatalogRow, StatusReport

# Imported inside functions: each flag loads only its own use case; -h and the reading flags load no
# heavy library they do not need (start-up; tests/integration/test_imports.py).

PROG = "libpanda-app-manager"
FLAGS = "htkdscupl"
VALUED = "igbr"
EXIT_OK, EXIT_USAGE = 0, 2
NO_APP_STATE = "inactive (none installed)"  # LPAM's `-t` without an app
HEADER = ("Repository", "Branch", "App", "Service", "Enabled", "Running", "Description")
USAGE = f"""\
usage: {PROG} [-d] [-l] [-c] [-t] [-i APP | -u] [-g OWNER/REPO [-b BRANCH]]
                            [-r OWNER/REPO] [-p] [-s] [-k] [-h]

LPAM's command line, on top of lpam: each flag edits lpam's default desired state
($LPAM_ROOT/etc/lpam/desired-state.yaml, LPAM_ROOT default /) and applies it, or asks it.

  -d               the apps of every repository: a tab-separated table (LPAM's, for bluezone);
                   Enabled is yes for each installed app; Service is the app's unit
                   (`none`: it names none)
  -l               the app names
  -c               the installed apps, one a line, or None
  -t               each installed app's service, as its service manager sees it: a
                   line per app, beginning with its name
  -i APP           enable APP and apply (install, start): it replaces the apps that claim a
                   resource APP claims (the panda...) and runs beside the others; in a
                   version-1 desired state (one app) it replaces the app
  -u               no app: stop and uninstall every installed app
  -g OWNER/REPO    add a GitHub repository of apps (acted on after the other flags)
  -b BRANCH        with -g: its branch (default: the repository's default branch)
  -r OWNER/REPO    remove a repository (not one an installed app comes from)
  -p               fetch every repository and apply (branches move to their tips)
  -s / -k          start / stop the installed app
  -h               this help

Flags run in the order given and stop at the first failure. Exit 0 only on success;
2 on a usage error. LPAM's interactive menu (no flags) is gone: usage, exit 2.
The service manager is lpam's choice ($LPAM_SERVICES: systemd or supervisor)."""


class UsageError(Exception):
    """The command line is wrong: nothing was done (exit 2)."""


class NoFlag(UsageError):
    """No flag at all, where LPAM opened its menu: the usage is what helps (exit 2)."""


@dataclass
class Command:
    """The parsed command line: the flags in order, and the repository to add last."""

    actions: list[tuple[str, str | None]] = field(default_factory=list)
    repository: str | None = None
    branch: str | None = None
    help: bool = False


def parse(argv: Sequence[str]) -> Command:
    """getopts' rules: options until `--` or the first word that is not one; a flag of
    VALUED takes the rest of its word, else the next word (whatever it looks like)."""
    pairs: list[tuple[str, str | None]] = []
    index = 0
    while index < len(argv):
        word = argv[index]
        index += 1
        if word == "--":
            break
        if not word.startswith("-") or word == "-":
            index -= 1
            break
        for at, flag in enumerate(word[1:], start=1):
            if flag in VALUED:
                value = word[at + 1:]
                if not value:
                    if index >= len(argv):
                        raise UsageError(f"option -{flag} needs a value")
                    value = argv[index]
                    index += 1
                pairs.append((flag, value))
                break
            if flag not in FLAGS:
                raise UsageError(f"unknown option -{flag}")
            pairs.append((flag, None))
    if index < len(argv):
        raise UsageError(f"unexpected argument {argv[index]!r}")
    return _command(pairs)


def _command(pairs: list[tuple[str, str | None]]) -> Command:
    command = Command()
    for flag, value in pairs:
        if value is not None and (not value or value.startswith("-")):
            raise UsageError(f"option -{flag}: {value!r} is refused (a value may not be empty "
                             "or start with '-')")
        if flag == "h":
            command.help = True
        elif flag in "gb":
            if getattr(command, "repository" if flag == "g" else "branch") is not None:
                raise UsageError(f"option -{flag} given twice")
            setattr(command, "repository" if flag == "g" else "branch", value)
        else:
            command.actions.append((flag, value))
    if command.branch is not None and command.repository is None:
        raise UsageError("-b BRANCH goes with -g OWNER/REPO")
    if not command.help and not command.actions and command.repository is None:
        raise NoFlag("no flag given (LPAM's interactive menu is gone): give one of the "
                     "flags above")
    return command


def table(rows: Sequence[CatalogRow]) -> str:
    """LPAM's `-d` output: the header, then one line per app; every line ends in \\n."""
    lines = ["\t".join(HEADER)]
    for row in rows:
        yes = {True: "yes", False: "no"}
        cells = [row.repository, row.ref, row.app, row.named_service, yes[row.installed],
                 yes[row.running], f'"{row.description}"']
        lines.append("\t".join(bluezone_safe(cell) for cell in cells))
    return "".join(line + "\n" for line in lines)


def lpam_text(flag: str, shown: StatusReport) -> str:
    """LPAM's answer to a reading flag, rendered from the status report: `-d` the table,
    `-l` the app names, `-c` the installed apps (LPAM's `current:`, which named one), `-t`
    each installed app's unit as its manager sees it, one line per app that begins with
    the app's name: LPAM had one app, and with several a bare unit state says of whom it
    speaks only to one who knows each app's unit."""
    if flag == "d":
        return table(shown.listed())
    if flag == "l":
        return " ".join(dict.fromkeys(r.app for r in shown.listed())) + "\n"
    if flag == "c":
        return ("\n".join(a.name for a in shown.installed) or "None") + "\n"
    if not shown.installed:
        return NO_APP_STATE + "\n"
    return "".join(f"{a.name}: " + (a.unit.said if a.unit is not None else
                                     "names no service (no `service` file): lpam's record "
                                     f"says {a.said}") + "\n"
                   for a in shown.installed)


def bluezone_safe(text: str) -> str:
    """`text` in ASCII that bluezone's decoding turns back into `text` (module docstring)."""
    out = []
    for char in text:
        if char == "\\":
            out.append("\\\\")
        elif ord(char) < 32 or ord(char) == 127:
            out.append(" ")
        elif ord(char) < 128:
            out.append(char)
        else:
            out.append("".join(f"\\x{byte:02x}" for byte in char.encode("utf-8", "replace")))
    return "".join(out)


def run(machine: Machine, command: Command) -> None:
    """Each flag in order, `-g` last (LPAM's order); the first failure raises."""
    for flag, value in command.actions:
        _act(machine, flag, value)
    if command.repository is not None:
        from reconciler.workflow.editing import add_repository

        done = add_repository(machine, command.repository, command.branch, by=PROG,
                              options=_options(), report=_report())
        print(f"Repository {command.repository} "
              f"{'added' if done.changed else 'already present'}; {done.applied.app}.")


def _act(machine: Machine, flag: str, value: str | None) -> None:
    from reconciler.workflow import editing, inventory

    if flag in "dlct":
        print(lpam_text(flag, inventory.report(machine)), end="")
    elif flag in "iu":
        done = editing.enable_app(machine, value, by=PROG, options=_options(),
                                  report=_report())
        print(f"{'App ' + str(value) if value else 'No app'} enabled; {done.applied.app}.")
    elif flag == "r":
        assert value is not None
        editing.remove_repository(machine, value, by=PROG, options=_options(),
                                  report=_report())
        print(f"Repository {value} removed.")
    elif flag == "p":
        updated = editing.update(machine, options=_options(), report=_report())
        print(f"Updated: {counted(updated.steps, 'step')}; {updated.app}.")
    elif flag in "sk":
        _operate(machine, flag)


def _operate(machine: Machine, flag: str) -> None:
    from reconciler.workflow.operate import operate_installed
    from schemas.operator import OperatorAction

    action = OperatorAction.START if flag == "s" else OperatorAction.STOP
    print(operate_installed(machine, action, file=None, force=False, options=_options(),
                            report=_report()))


def _options() -> ApplyOptions:
    """lpam's defaults, and who asks: the user who ran this command (workflow/actor.py)."""
    from reconciler.workflow.actor import user
    from reconciler.workflow.applying import ApplyOptions

    return ApplyOptions(by=user(PROG))


def _report() -> Report:
    from reconciler.frontends.console import Terminal

    return Terminal()


def _layout() -> Layout:
    from reconciler.base.layout import Layout

    root = os.environ.get("LPAM_ROOT") or "/"
    return Layout(Path(root).resolve())


def _machine() -> Machine:
    from reconciler.workflow.machine import Machine

    return Machine.at(_layout())


def _error(message: str) -> str:
    return f"{PROG}: error: {message}"


def _fail(message: str) -> None:
    print(_error(message), file=sys.stderr)


def one_line(exc: LpamError) -> str:
    """The error as the CLI renders it (with its file:line:col), on one line."""
    lines = exc.render().removeprefix(f"{exc.word}: ").splitlines()
    text = lines[0]
    hint = next((line.strip() for line in lines[1:] if line.strip().startswith("hint:")), None)
    return f"{text} ({hint})" if hint else text


def main(argv: Sequence[str] | None = None) -> int:
    from reconciler.frontends.console import (
        debug_log,
        exit_code,
        raise_signals_where_lpam_stands,
    )

    try:
        command = parse(sys.argv[1:] if argv is None else argv)
    except NoFlag as exc:
        print(USAGE, file=sys.stderr)
        _fail(str(exc))
        return EXIT_USAGE
    except UsageError as exc:
        _fail(f"{exc} (see {PROG} -h)")
        return EXIT_USAGE
    raise_signals_where_lpam_stands()
    keep_writes_private()  # nothing lpam makes is writable by group or others (base/modes.py)

    def body() -> int:
        if command.help:  # guarded too: `-h | head` closes stdout early
            print(USAGE)
        else:
            run(_machine(), command)
        return EXIT_OK

    return exit_code(
        body, bug=lambda: debug_log(_layout()),
        failed=lambda exc: f"{PROG}: {exc.word}: {one_line(exc)}",
        interrupted=lambda: _error("interrupted: lpam recorded where it stood; `lpam apply` "
                                   "goes on from there"),
        internal=lambda log: _error(f"internal error; details in {log}"))


if __name__ == "__main__":
    sys.exit(main())
