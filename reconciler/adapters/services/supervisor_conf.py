"""supervisord's configuration as lpam writes it: the pure half of the supervisor adapter.

lpam owns two kinds of file under `<root>/etc/lpam/supervisor/`: `supervisord.conf` (the
daemon: its socket, pid file and log, and `[include] files=programs/*.conf`) and one
`programs/<unit>.conf` per `Unit`, a `[program:<unit>]` section. This module renders them
and reads back the few settings the adapter needs; it does no I/O.

A value goes through four readers before it reaches a process, and each can bend it:
1. configparser (supervisor's `UnhosedConfigParser`, a RawConfigParser): one value per
   line, stripped, and `;` or `#` after any whitespace character starts a comment;
2. `%(here)s` is replaced textually in every value of every section once a file has been
   included (before, and regardless of, `%%` escaping);
3. `%`-expansion (`%(ENV_HOME)s`, `%(program_name)s`…): a literal `%` must be `%%`;
4. then `command` is split by `shlex.split` (POSIX rules), and `environment` by a
   non-POSIX `shlex.shlex` whose tokens lose every leading and trailing quote character.
So `command` quotes each argument in single quotes, cut into pieces so that no `;`/`#`
follows whitespace and no `%` is followed by `(`; an environment value is quoted with
whichever quote it does not contain. What no quoting can carry (a line break anywhere; an
environment value holding both quote characters where it needs quoting, or whitespace then
`;`/`#`; the text `%(here)s` outside a command) is refused with a ServiceError naming the
unit and the value, never written in a shape supervisord would read back differently.
"""

from __future__ import annotations

import math
import re
import string
from pathlib import Path

from reconciler.base.errors import ServiceError
from reconciler.base.text import printable
from reconciler.base.unit import Unit

HERE = "%(here)s"
LOG_MAX_BYTES = "10MB"  # per app, with LOG_BACKUPS old files: bounded on a Pi's SD card
LOG_BACKUPS = 3

_BREAKS = ("\n", "\r", "\x00")
# configparser's inline comments: `;` or `#` right after any character str.isspace() accepts.
_COMMENT_CUTS = re.compile(r"(?=[;#])|(?<=%)")
# The characters non-POSIX shlex (as supervisor configures it) keeps in one bare word.
_ENV_WORD = frozenset(string.ascii_letters + string.digits + "_" + "/.+-():")
_ENV_KEY = re.compile(r"[A-Za-z0-9_/.+\-():]+")
_USER = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*\$?")


def _refuse(unit: str, what: str, value: str, why: str) -> ServiceError:
    return ServiceError(
        f"unit {unit}: supervisord cannot be given {what} {value!r}: {why}",
        hint="change the value (in the app's catalog or parameters), or run the app under "
        "systemd (--services systemd)",
    )


def _no_breaks(unit: str, what: str, value: str) -> None:
    if any(c in value for c in _BREAKS):
        raise _refuse(unit, what, value, "it holds a line break or NUL, and supervisord's "
                      "configuration has one value per line")


def _comment_cut(value: str) -> bool:
    """True when configparser would take part of `value` for a comment."""
    return any(value[i] in ";#" and value[i - 1].isspace() for i in range(1, len(value)))


def quote_arg(arg: str) -> str:
    """One argument as a shlex-quoted word, before `%` escaping. Pieces are cut before each
    `;`/`#` and after each `%`, and each piece is single-quoted: whitespace is then never
    followed by a comment character, nor `%` by `(` (so no `%(here)s` can appear)."""
    if arg == "":
        return "''"
    pieces = [p for p in _COMMENT_CUTS.split(arg) if p]
    return "".join("'" + p.replace("'", "'\\''") + "'" for p in pieces)


def command(unit: str, argv: tuple[str, ...] | list[str]) -> str:
    """The `command=` value whose `%`-expansion and `shlex.split` give back `argv` exactly."""
    if not argv:
        raise ServiceError(f"unit {unit}: no command to run")
    for arg in argv:
        _no_breaks(unit, "the argument", arg)
    return " ".join(quote_arg(a) for a in argv).replace("%", "%%")


def env_value(unit: str, key: str, value: str) -> str:
    """One environment value in the form supervisor's KEY=value,… parser gives back."""
    what = f"the value of {key}"
    _no_breaks(unit, what, value)
    if _comment_cut(value):
        raise _refuse(unit, what, value, "whitespace followed by ';' or '#' starts a comment "
                      "there, and no quoting prevents it")
    if HERE in value:
        raise _refuse(unit, what, value, f"supervisord replaces {HERE} everywhere")
    quotes = "'\""
    if '"' not in value and value[:1] != "'" and value[-1:] != "'":
        quoted = f'"{value}"'
    elif "'" not in value and value[:1] != '"' and value[-1:] != '"':
        quoted = f"'{value}'"
    elif (value[:1] in _ENV_WORD and value[-1:] not in quotes
          and all(c in _ENV_WORD or c in quotes for c in value)):
        quoted = value
    else:
        raise _refuse(unit, what, value, "it needs quoting but holds both quote characters "
                      "(or begins or ends with one), which supervisord strips")
    return quoted.replace("%", "%%")


def environment(unit: str, env: dict[str, str]) -> str:
    parts = []
    for key, value in env.items():
        if not _ENV_KEY.fullmatch(key):
            raise _refuse(unit, "the environment variable name", key,
                          "use letters, digits and _")
        parts.append(f"{key}={env_value(unit, key, value)}")
    return ",".join(parts)


def literal(unit: str, what: str, value: str) -> str:
    """A value configparser and `%`-expansion give back unchanged (a path, a user)."""
    _no_breaks(unit, what, value)
    if value != value.strip() or _comment_cut(value) or value[:1] in (";", "#"):
        raise _refuse(unit, what, value, "supervisord's configuration would strip it or "
                      "read part of it as a comment")
    if HERE in value:
        raise _refuse(unit, what, value, f"supervisord replaces {HERE} everywhere")
    return value.replace("%", "%%")


def _path(unit: str, what: str, path: Path) -> str:
    if not path.is_absolute():
        raise ServiceError(f"unit {unit}: {what} {str(path)!r} is not an absolute path")
    return literal(unit, what, str(path))


def program(unit: Unit, *, name: str, log: Path) -> str:
    """The `programs/<name>.conf` of `unit`.

    Where supervisord cannot keep a promise of `Unit`, the nearest setting is used:
    `startretries` counts failed starts (an exit within `startsecs`) rather than restarts
    within `start_limit_seconds`, and a program that ran longer is restarted at once
    (supervisord has no `restart_seconds`; it backs off 1, 2, 3… s between failed starts).
    """
    lines = [
        f"; written by lpam: {_one_line(unit.description or name)}",
        "; do not edit: lpam rewrites it at every install",
        f"[program:{name}]",
        f"command={command(name, unit.argv)}",
        f"directory={_path(name, 'the directory', unit.directory)}",
    ]
    if unit.environment:
        lines.append(f"environment={environment(name, unit.environment)}")
    if unit.user is not None:
        if not _USER.fullmatch(unit.user):
            raise _refuse(name, "the user", unit.user, "not a user name")
        lines.append(f"user={literal(name, 'the user', unit.user)}")
    lines += [
        "autostart=false",  # lpam decides when an app runs, after a reboot too
        "autorestart=unexpected",
        "startsecs=1",
        f"startretries={max(unit.start_limit, 0)}",
        "stopsignal=TERM",
        f"stopwaitsecs={max(math.ceil(unit.stop_seconds), 1)}",
        "stopasgroup=true",  # roslaunch has children: TERM and KILL reach the whole group
        "killasgroup=true",
        "redirect_stderr=true",
        f"stdout_logfile={_path(name, 'the log file', log)}",
        f"stdout_logfile_maxbytes={LOG_MAX_BYTES}",
        f"stdout_logfile_backups={LOG_BACKUPS}",
    ]
    return "\n".join(lines) + "\n"


def supervisord(
    *, root: Path, socket: Path, pidfile: Path, logfile: Path, childlogdir: Path,
    directory: Path,
) -> str:
    """`supervisord.conf`: a daemon reachable only through a unix socket of mode 0700 (no
    TCP, no password: whoever can open the socket is already that user)."""
    def path(what: str, value: Path) -> str:
        return _path("supervisord", what, value)

    sock = path("the socket", socket)
    return "\n".join([
        f"; written by lpam for the root {_one_line(str(root))}",
        "; do not edit: lpam rewrites it whenever it starts supervisord",
        "[supervisord]",
        f"logfile={path('the log file', logfile)}",
        "logfile_maxbytes=1MB",
        "logfile_backups=3",
        "loglevel=info",  # `spawned:` lines are how restarts are counted
        f"pidfile={path('the pid file', pidfile)}",
        f"childlogdir={path('the log folder', childlogdir)}",
        f"directory={path('the run folder', directory)}",
        "identifier=lpam",
        "umask=022",
        "",
        "[unix_http_server]",
        f"file={sock}",
        "chmod=0700",
        "",
        "[rpcinterface:supervisor]",
        "supervisor.rpcinterface_factory=supervisor.rpcinterface:make_main_rpcinterface",
        "",
        "[supervisorctl]",
        f"serverurl=unix://{sock}",
        "",
        "[include]",
        "files=programs/*.conf",
        "",
    ])


def settings(text: str) -> dict[str, str]:
    """`key=value` lines of a file this module wrote, `%%` unescaped (meaningful for the
    literal values: paths and numbers)."""
    found: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, value = line.partition("=")
        if sep and not line.startswith((";", "#", "[")):
            found[key.strip()] = value.strip().replace("%%", "%")
    return found


def _one_line(text: str) -> str:
    return printable(text, " ")
