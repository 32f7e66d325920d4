"""`lpam`: the only place that prints and exits.

Maps every LpamError to one short message (file:line:column for documents) and exit 1;
anything unexpected is a bug: its traceback goes to `<root>/var/log/lpam/debug.log`, and
the user gets one line pointing there. Heavy libraries (dulwich, networkx) are imported
only by the commands that need them, so `lpam --version` and `lpam status` start fast.

Each `cmd_*` parses nothing itself: it takes the parsed arguments, calls one use case of
reconciler/workflow (where every rule lives: locks, gates, holds, defaults), renders what
it returns and reports, and returns the exit code.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import shlex
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reconciler import __version__
from reconciler.base.errors import LpamError
from reconciler.base.layout import KEEP_GENERATIONS, Layout
from reconciler.base.modes import keep_writes_private
from reconciler.base.text import columns, counted, printable
from reconciler.frontends.console import (
    Calling,
    Terminal,
    debug_log,
    exit_code,
    raise_signals_where_lpam_stands,
)
from reconciler.workflow.defaults import SCRIPT_TIMEOUT

if TYPE_CHECKING:  # imported lazily at run time: `lpam --version` must stay fast
    from reconciler.workflow.applying import ApplyOptions
    from reconciler.workflow.events import Event
    from reconciler.workflow.history import Made
    from reconciler.workflow.machine import Machine
    from schemas.record import HistoryEntry

# Imported inside functions: each command loads only its own use case (start-up;
# tests/integration/test_imports.py holds it).

EXIT_OK, EXIT_ERROR, EXIT_CHANGES = 0, 1, 2
VALIDATE_KINDS = ("desired-state", "catalog", "repository", "agent", "plan")
"""The values of reconciler.workflow.validation.Kind, spelled out: the parser is built before any
command runs, and `lpam --version` must not import the schemas."""
OPERATOR_ACTIONS = (
    ("start", "start the installed apps (or APP) now (ends an operator stop)"),
    ("stop", "stop the installed apps (or APP); each stays stopped until `lpam start` or a "
     "change of the desired state"),
    ("restart", "stop and start the installed apps (or APP)"),
)
"""schemas.operator.OperatorAction's values (spelled out for the same reason), each with
its help."""
BLE_WRITES = ("bonded", "open")
"""schemas.bluetooth.Writes's values (spelled out for the same reason)."""
MAX_WINDOW = 3600
"""The longest pairing window `lpam ble pair --seconds` opens: a window is short."""


def _at_least_one(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError("keep at least 1 (the installed generation)")
    return value


Option = tuple[tuple[str, ...], dict[str, Any]]
OPTIONS: dict[str, Option] = {
    "file": (("-f", "--file"), {"type": Path, "help": "desired state (default: under --root)"}),
    "json": (("--json",), {"action": "store_true"}),
    "yes": (("--yes",), {"action": "store_true"}),
    "config": (("--config",), {"type": Path, "help": "agent.yaml (default: under --root)"}),
    "lock-timeout": (("--lock-timeout",), {
        "type": float, "default": None, "metavar": "SECONDS",
        "help": "wait this long for a running apply to finish (default 10)"}),
    "script-timeout": (("--script-timeout",), {
        "type": float, "default": SCRIPT_TIMEOUT, "metavar": "SECONDS",
        "help": "kill an app script running longer than this (default 600)"}),
    "network-timeout": (("--network-timeout",), {
        "type": float, "default": 60.0, "metavar": "SECONDS",
        "help": "give up on a git server that does not answer for this long (default 60)"}),
    "services": (("--services",), {
        "choices": ("systemd", "supervisor"), "default": None,
        "help": "service manager that runs the app (default: $LPAM_SERVICES, else systemd "
        "where it runs, else supervisord)"}),
    "keep-generations": (("--keep-generations",), {
        "type": _at_least_one, "default": KEEP_GENERATIONS, "metavar": "N",
        "help": "good generations kept on disk for `lpam rollback` "
        f"(default {KEEP_GENERATIONS})"}),
    "wait": (("--wait",), {
        "type": float, "default": 0.0, "metavar": "SECONDS",
        "help": "wait up to SECONDS for closed update gates to open before the cutover; "
        "still closed: exit 75, deferred (default 0)"}),
    "force": (("--force",), {
        "action": "store_true", "help": "ignore the update gates (the vehicle may be moving)"}),
    "writes": (("--writes",), {
        "choices": BLE_WRITES, "default": "bonded",
        "help": "who may change the car over Bluetooth: bonded phones only (default), or "
        "open: any phone in range, as bluezone allowed (for a lab)"}),
}
"""Every option more than one command takes, declared once. `--lock-timeout` defaults to
None: each use case knows how long its lock waits (reconciler/workflow/defaults.py)."""
GLOBAL = ("lock-timeout", "script-timeout", "network-timeout", "services", "keep-generations")
"""The options the README names beside `--root`: each is accepted before the command as
`--root` is (`lpam --services systemd apply`) and after it by the commands that use it.
argparse copies a subcommand's defaults over what the main parser read, so the
subcommands declare them with `default=SUPPRESS` and the main parser alone holds the
defaults: written after the command, an option wins; before it, it is no longer lost."""

New = Callable[[str, str], argparse.ArgumentParser]


def parser() -> argparse.ArgumentParser:
    """lpam's arguments; reconciler/frontends/helptext.py keeps its `--help` as text."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--root", default=argparse.SUPPRESS,
        help="put every path lpam touches under ROOT (default: $LPAM_ROOT or /)",
    )
    lpam = argparse.ArgumentParser(
        prog="lpam", parents=[common],
        description="Make this vehicle's apps match a declared desired state.",
    )
    lpam.add_argument("--version", action="version", version=f"lpam {__version__}")
    for name in GLOBAL:
        flags, options = OPTIONS[name]
        lpam.add_argument(*flags, **options)
    sub = lpam.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def new(name: str, what: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, parents=[common], help=what)

    for declare in (_plan_apply, _status_operate, _logs_history_rollback, _sync_agent,
                    _gates_install_bundle, _fleet_pin_services, _provenance,
                    _validate_import):
        declare(new)
    return lpam


def _add(parser: argparse.ArgumentParser, *names: str, **override: Any) -> None:
    """The shared options `names`, in the order `--help` shows them; `override` changes
    fields (`help=`, `default=`) of each of them."""
    for name in names:
        flags, options = OPTIONS[name]
        own = {"default": argparse.SUPPRESS} if name in GLOBAL else {}
        parser.add_argument(*flags, **{**options, **own, **override})


def _plan_apply(new: New) -> None:
    plan = new("plan", "show what apply would change")
    _add(plan, "file")
    _add(plan, "json", help="print the plan as JSON")
    plan.add_argument("-o", "--out", type=Path, help="save the plan for `lpam apply PLANFILE`")
    plan.add_argument("--detailed-exitcode", action="store_true",
                      help="exit 0 without changes, 2 with changes, 1 on error")
    plan.add_argument("--offline", action="store_true",
                      help="use no network: plan from what the last fetch brought")
    _add(plan, "lock-timeout", "network-timeout", "services")

    apply = new("apply", "make the machine match")
    apply.add_argument("planfile", nargs="?", type=Path, help="a plan saved by plan --out")
    _add(apply, "file")
    _add(apply, "yes", help="apply without asking")
    _add(apply, "lock-timeout", "script-timeout", "network-timeout", "services",
         "keep-generations")
    apply.add_argument("--release", action="store_true",
                       help="end a rollback's hold (and a local override of the fleet's "
                       "file) and apply the desired state again")
    _add(apply, "wait")


def _status_operate(new: New) -> None:
    _add(new("status", "show repositories and apps"), "json", "services")
    for action, what in OPERATOR_ACTIONS:
        operate = new(action, what)
        operate.add_argument("app", nargs="?", metavar="APP",
                             help="that installed app only (default: every installed app)")
        _add(operate, "file", help="desired state whose update gates apply (default: under "
             "--root)")
        _add(operate, "wait", "force", "lock-timeout", "services", "script-timeout")


def _logs_history_rollback(new: New) -> None:
    logs = new("logs", "the installed apps' recent output")
    logs.add_argument("app", nargs="?", metavar="APP",
                      help="that installed app only (default: every installed app, each "
                      "line prefixed with its name when there are several)")
    logs.add_argument("-n", "--lines", type=int, default=50, help="how many lines (default 50)")
    logs.add_argument("-f", "--follow", action="store_true", help="keep printing new output")
    _add(logs, "services")

    _add(new("history", "the generations made current, newest last"), "json")

    rollback = new("rollback", "make the previous good generation current again, offline")
    _add(rollback, "file",
         help="desired state the rollback holds against (default: under --root)")
    _add(rollback, "yes", help="roll back without asking")
    _add(rollback, "wait", "force", "lock-timeout", "services", "script-timeout")


def _sync_agent(new: New) -> None:
    sync = new("sync", "one pass of following the desired-state repository")
    _add(sync, "config")
    sync.add_argument("--fetch-only", action="store_true",
                      help="fetch the source and what it pins, record, change nothing")
    sync.add_argument("--bundle", type=Path, metavar="FILE",
                      help="take the source and what it pins from a bundle: no network")
    _add(sync, "lock-timeout", "network-timeout", "services", "script-timeout",
         "keep-generations")
    _add(sync, "wait", default=None, help="wait up to SECONDS for closed update gates "
         "(default: agent.yaml's gate_wait_seconds)")

    agent = new("agent", "follow the desired-state repository: sync passes forever")
    _add(agent, "config")
    agent.add_argument("--once", action="store_true", help="one pass, then exit with its code")
    _add(agent, "network-timeout", "services", "script-timeout", "lock-timeout")

    ble = new("ble", "serve the field's phone app (Privzone) over Bluetooth LE until stopped")
    _bluez_options(ble)
    _add(ble, "writes", "network-timeout", "services")
    _ble_actions(ble)


def _bluez_options(parser: argparse.ArgumentParser, *, default: Any = None) -> None:
    """`--adapter` and `--bus`: `lpam ble`'s, and again after its actions (`lpam ble pair
    --bus X`), there with no default of their own (argparse would copy it over `lpam ble
    --bus X pair`'s)."""
    own = {} if default is None else {"default": default}
    parser.add_argument("--adapter", **(own or {"default": "/org/bluez/hci0"}),
                        help="the BlueZ adapter's object path (default: /org/bluez/hci0)")
    parser.add_argument("--bus", metavar="ADDRESS", **own,
                        help="the system D-Bus's address (default: $DBUS_SYSTEM_BUS_ADDRESS, "
                        "else the system's)")


def _window_seconds(text: str) -> int:
    value = int(text)
    if not 1 <= value <= MAX_WINDOW:
        raise argparse.ArgumentTypeError(f"give 1 to {MAX_WINDOW} seconds")
    return value


def _ble_actions(ble: argparse.ArgumentParser) -> None:
    """`lpam ble pair|phones|forget`: who may pair with the car (without one: serve)."""
    actions = ble.add_subparsers(dest="ble_action", metavar="ACTION")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--root", default=argparse.SUPPRESS, help="as `lpam --root`")
    _bluez_options(common, default=argparse.SUPPRESS)
    pair = actions.add_parser("pair", parents=[common], help="let a phone pair with the car "
                              "for a while: its writes are accepted from then on")
    pair.add_argument("--seconds", type=_window_seconds, default=120,
                      help="how long the car is pairable and discoverable (default 120)")
    actions.add_parser("phones", parents=[common], help="the phones bonded with the car")
    forget = actions.add_parser("forget", parents=[common],
                                help="remove a bonded phone: its writes are refused again")
    forget.add_argument("address", metavar="ADDRESS", help="as `lpam ble phones` lists it")


def _gates_install_bundle(new: New) -> None:
    gates = new("gates", "the update gates now: speed, locks, time window")
    _add(gates, "file", "json")

    _add(new("install-agent", "install the systemd units that run the agent on this car"),
         "config", "services")
    _add(new("install-ble", "install the systemd unit that runs `lpam ble` on this car "
             "(it replaces bluezone's unit)"), "writes", "services")

    bundle = new("bundle", "offline bundles of the desired state and what it pins")
    bundle.add_argument("action", choices=("create",))
    bundle.add_argument("out", type=Path, help="the bundle file to write")
    bundle.add_argument("--source", help="desired-state repository (default: agent.yaml's)")
    bundle.add_argument("--branch", help="its branch (default: agent.yaml's, else main)")
    _add(bundle, "network-timeout")


def _fleet_pin_services(new: New) -> None:
    fleet = new("fleet", "the fleet's status, read from a clone of its repository")
    fleet.add_argument("action", choices=("status", "report"),
                       help="status: one line per car; report: a static page (HTML + SVG) "
                       "of every car's state and timeline")
    fleet.add_argument("-o", "--out", type=Path, default=Path("fleet-report"),
                       help="report: the folder to write index.html in "
                       "(default: fleet-report)")
    fleet.add_argument("--repo", type=Path, default=Path("."),
                       help="a clone of the desired-state repository (default: here)")
    fleet.add_argument("--branch", default="main", help="the branch the cars follow")
    _add(fleet, "json")

    pin = new("pin", "pin every branch or tag of a desired state to its commit now")
    pin.add_argument("file", nargs="?", type=Path, help="desired state (default: under --root)")
    pin.add_argument("--catalogs", action="store_true",
                     help="also report the ROS repositories of the app it names")
    pin.add_argument("--dry-run", action="store_true", help="say what would change only")
    _add(pin, "network-timeout")
    _add(pin, "lock-timeout", help="wait this long for a running apply to finish (default 60)")

    services = new("services", "the service manager lpam started (supervisord)")
    services.add_argument("action", choices=("shutdown",),
                          help="shutdown: stop the supervisord lpam started for this root")


def _provenance(new: New) -> None:
    prov = new("provenance", "which software ran while a data file was recorded")
    prov.add_argument("files", nargs="*", type=Path, metavar="FILE",
                      help="data files (CSV, candump, ROS bag, or any: its time)")
    prov.add_argument("--at", metavar="TIME", type=_moment,
                      help="what ran at TIME (ISO 8601, or seconds since the epoch)")
    prov.add_argument("--between", nargs=2, metavar=("T1", "T2"), type=_moment,
                      help="what ran at any instant from T1 to T2")
    prov.add_argument("--desired", action="store_true",
                      help="print a pinned desired state that installs that software again")
    prov.add_argument("--repo", type=Path, metavar="DIR",
                      help="read a car's published timeline from this clone of the fleet "
                      "repository instead of this car's")
    prov.add_argument("--vehicle", metavar="ID", help="with --repo: which car's")
    prov.add_argument("--stamp", action="store_true",
                      help="write FILE.provenance.json beside each finished data file the "
                      "apps declare (the agent does this each pass)")
    _add(prov, "json")


def _moment(text: str) -> datetime:
    """A time as a user writes it: ISO 8601 (UTC unless it says otherwise) or epoch seconds."""
    try:
        moment = datetime.fromtimestamp(float(text), tz=timezone.utc)
    except (ValueError, OverflowError, OSError):
        try:
            moment = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a time: write e.g. 2026-03-14T10:15:00Z or 1773483300"
            ) from None
    return moment if moment.tzinfo is not None else moment.replace(tzinfo=timezone.utc)


def _validate_import(new: New) -> None:
    validate = new("validate", "check any document lpam reads, by the kind its keys show")
    validate.add_argument("path", type=Path)
    validate.add_argument("--kind", choices=VALIDATE_KINDS,
                          help="read PATH as this kind instead of deciding from its keys")

    imp = new("import-lpam", "write a desired state equivalent to an LPAM installation")
    imp.add_argument("etc_dir", nargs="?", type=Path,
                     help="LPAM's folder (default: <root>/etc/libpanda.d)")
    imp.add_argument("-o", "--output", type=Path, help="write here instead of printing")


def _layout(args: argparse.Namespace) -> Layout:
    root = getattr(args, "root", None) or os.environ.get("LPAM_ROOT") or "/"
    return Layout(Path(root).resolve())


def entry() -> int:
    """The `lpam` process. It is short-lived and allocates little after its imports, so
    cyclic GC passes over pydantic's and dulwich's import-time objects only cost time, at
    start and again at exit (measured in docs/benchmarks.md): they are switched off."""
    gc.disable()
    try:
        return main()
    except KeyboardInterrupt:  # before a command began (parsing arguments): nothing ran
        print("interrupted: nothing was changed", file=sys.stderr)
        return 130
    finally:
        gc.freeze()


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    raise_signals_where_lpam_stands()
    keep_writes_private()  # nothing lpam makes is writable by group or others (base/modes.py)
    layout = _layout(args)
    for name, value in vars(args).items():
        if isinstance(value, Path):  # said back in hints and records: run from anywhere
            setattr(args, name, Path(os.path.abspath(value)))
    args.calling = Calling.of(layout.root, services=args.services)
    spell = args.calling.spell
    return exit_code(
        lambda: int(COMMANDS[args.command](args, layout)), bug=lambda: debug_log(layout),
        failed=lambda exc: spell(exc.render()), interrupted=lambda: spell(_interrupted(args)),
        internal=lambda log: f"error: internal error in lpam {__version__}; details in {log}")


def _say(args: argparse.Namespace, text: str, *, err: bool = False) -> None:
    """Print `text` with every command it suggests spelled for this root (`Calling`)."""
    calling: Calling = getattr(args, "calling", Calling())
    print(calling.spell(text), file=sys.stderr if err else sys.stdout)


def _terminal(args: argparse.Namespace) -> Terminal:
    return Terminal(getattr(args, "calling", None))


def _interrupted(args: argparse.Namespace) -> str:
    if args.command in CHANGES_THE_CAR:
        return ("interrupted: lpam recorded where it stood (a script under way is stopped "
                f"with its whole process group); run `{again(args)}` to resume")
    return "interrupted: nothing was changed"


CHANGES_THE_CAR = ("apply", "sync", "agent", "start", "stop", "restart", "rollback")


RESUMED_WITH = ("script-timeout", "network-timeout", "lock-timeout", "keep-generations")
"""The options a resumed command needs as this one had them (a long install needs its
longer --script-timeout again): repeated when given other than their defaults."""


def again(args: argparse.Namespace) -> str:
    """The command that goes on from where this one stopped, as the user would type it in
    any directory: the same root and desired-state file, absolute (a saved plan is stale
    once part of it ran; a rollback's -f names only the gates' file, and the apply that
    finishes it holds to the generation it returns to)."""
    from reconciler.workflow.operate import resumed_by

    calling: Calling = getattr(args, "calling", None) or Calling.of(
        _layout(args).root, services=getattr(args, "services", None))
    parts = calling.words
    for name in RESUMED_WITH:
        flags, options = OPTIONS[name]
        value = getattr(args, name.replace("-", "_"), options["default"])
        if value != options["default"]:
            parts += [flags[0], f"{value:g}" if isinstance(value, float) else str(value)]
    parts.append(resumed_by(args.command))
    if args.command in ("start", "stop", "restart") and getattr(args, "app", None):
        parts.append(args.app)  # a stop of one app goes on with that app, no other
    if args.command != "rollback" and getattr(args, "file", None) is not None:
        parts += ["-f", os.path.abspath(args.file)]
    if getattr(args, "config", None) is not None:
        parts += ["--config", os.path.abspath(args.config)]
    return shlex.join(parts)


def _desired_path(args: argparse.Namespace, layout: Layout) -> Path:
    return Path(args.file) if args.file else layout.desired_state


def _machine(args: argparse.Namespace, layout: Layout) -> Machine:
    from reconciler.workflow.machine import Machine

    return Machine.at(layout, services=getattr(args, "services", None),
                      network_timeout=getattr(args, "network_timeout", 60.0))


def _options(args: argparse.Namespace, **more: Any) -> ApplyOptions:
    """The run options a command was given (each use case supplies its own defaults), and
    who gave it: the user at this terminal (workflow/actor.py)."""
    from reconciler.workflow.actor import user
    from reconciler.workflow.applying import ApplyOptions

    return ApplyOptions(lock_timeout=args.lock_timeout, script_timeout=args.script_timeout,
                        resume=again(args), by=user("lpam"), **more)


def _ask(args: argparse.Namespace, question: str, *, what: str, verb: str) -> bool:
    """`--yes`, else the operator typing `yes` at a terminal; no terminal is an error."""
    if args.yes:
        return True
    if not sys.stdin.isatty():
        raise LpamError(f"{what} needs confirmation",
                        hint=f"pass --yes to {verb} without asking")
    return input(question).strip() == "yes"


def cmd_plan(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.core.planning.render import render
    from reconciler.workflow.planning import plan_file

    plan = plan_file(_machine(args, layout), _desired_path(args, layout), report=_terminal(args),
                     offline=args.offline, out=args.out, lock_timeout=args.lock_timeout)
    if args.json:
        print(plan.model_dump_json(indent=2))
    else:
        _say(args, render(plan))
        if args.out is not None:
            _say(args, f"\nSaved the plan to {args.out}; apply it with "
                 f"`lpam apply {shlex.quote(str(args.out))}`.")
    if args.detailed_exitcode and plan.has_changes:
        return EXIT_CHANGES
    return EXIT_OK


def cmd_apply(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.applying import apply_file, apply_plan_file

    if args.planfile is not None and args.file is not None:
        raise LpamError("give either a plan file or -f FILE, not both")
    options = _options(args, keep_generations=args.keep_generations, release=args.release,
                       wait=args.wait)
    if args.planfile is not None:
        print()
        done = apply_plan_file(_machine(args, layout), args.planfile, options=options,
                               report=_terminal(args))
    else:
        done = apply_file(_machine(args, layout), _desired_path(args, layout),
                          options=options, confirm=lambda plan: _confirm(args),
                          report=_terminal(args))
    if done.cancelled:
        print("Apply cancelled; nothing was changed.")
        return EXIT_ERROR
    if done.steps:
        print(f"\nApply complete: {counted(done.steps, 'step')}; {done.app}. "
              f"Script output: {done.log}")
    return EXIT_OK


def _confirm(args: argparse.Namespace) -> bool:
    if not _ask(args, "\nApply these changes? Only 'yes' is accepted: ", what="apply",
                verb="apply"):
        return False
    print()
    return True


def cmd_operate(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.operate import operate_installed
    from schemas.operator import OperatorAction

    _say(args, operate_installed(_machine(args, layout), OperatorAction(args.command),
                                 file=args.file, force=args.force,
                                 options=_options(args, wait=args.wait),
                                 report=_terminal(args), app=args.app))
    return EXIT_OK


def cmd_rollback(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.operate import roll_back

    def confirm(entries: list[HistoryEntry]) -> bool:
        said = ", ".join(f"{e.app} ({e.generation}, commit {e.commit[:12]}" +
                         (f", applied {e.time})" if len(entries) == 1 else ")")
                         for e in entries)
        print(f"Roll back to {said}" + ("?" if len(entries) == 1 else
                                        f", applied {entries[0].time}?"))
        return _ask(args, "Only 'yes' is accepted: ", what="rollback",
                    verb="roll back")

    done = roll_back(_machine(args, layout), file=args.file, force=args.force,
                     options=_options(args, wait=args.wait), confirm=confirm,
                     report=_terminal(args))
    if done is None:
        print("Rollback cancelled; nothing was changed.")
        return EXIT_ERROR
    _say(args, done)
    return EXIT_OK


def cmd_gates(args: argparse.Namespace, layout: Layout) -> int:
    """Each update gate now. Exit 0 when all are open, 75 when a cutover would be deferred."""
    from reconciler.base.errors import Deferred
    from reconciler.workflow.gates import gates_now

    now_ = gates_now(_machine(args, layout), _desired_path(args, layout))
    path, states = now_.path, now_.states
    if args.json:
        print(json.dumps({"desired_state": str(path), "gated": now_.gated,
                          "open": now_.open, "gates": [
                              {"name": s.name, "open": s.open, "detail": s.detail}
                              for s in states]}, indent=2))
    elif not now_.gated:
        print(f"No update gates: {path} has no `gates:`; a cutover may happen at any moment.")
    else:
        print(f"Update gates of {path}:")
        for s in states:
            print(f"  {s.name:<8} {'open' if s.open else 'CLOSED':<7} {s.detail}")
        print("A cutover may happen now." if now_.open else
              "A cutover now would be deferred (exit 75).")
    return EXIT_OK if now_.open else Deferred.exit_code


def cmd_logs(args: argparse.Namespace, layout: Layout) -> int:
    """The installed apps' output, or APP's (reconciler/workflow/logs.py says from where).
    Ctrl-C is how a follow (`-f`) ends: it ends quietly with 0, as `journalctl -f` does —
    not with "interrupted: nothing was changed" under the app's last line."""
    from reconciler.base.errors import Terminated
    from reconciler.frontends.console import EXIT_TERMINATED
    from reconciler.workflow.logs import app_logs, new_output

    machine = _machine(args, layout)
    shown = app_logs(machine, max(args.lines, 1), args.app)
    for note in shown.notes:
        print(f"note: {note}", file=sys.stderr)
    for line in shown.lines:
        print(line)
    if args.follow:
        sys.stdout.flush()
        try:
            for line in new_output(machine, shown):
                print(line, flush=True)
        except KeyboardInterrupt:
            return EXIT_OK
        except Terminated:
            return EXIT_TERMINATED
    return EXIT_OK


def cmd_history(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.history import history

    made = history(layout)
    if args.json:
        print(json.dumps([m.entry.model_dump(mode="json") for m in made], indent=2))
        return EXIT_OK
    if not made:
        print("No history yet: no apply has made an app current.")
        return EXIT_OK
    print("\n".join(history_lines(made)))
    return EXIT_OK


HISTORY_HEADER = ("Now", "Time", "App", "Generation", "Repository", "Commit", "Result",
                  "By", "Params")


def history_lines(made: Sequence[Made]) -> list[str]:
    """`lpam history` as a table: a header, then each generation made current, oldest
    first, `*` in the first column for what is installed now. Every column is as wide as
    its widest cell (a long repository name no longer shifts the rest of its row); with
    several apps, a blank line between the sets of apps, one block per apply. `By`: who
    asked for the apply (`-`: not recorded, an lpam before state record 8)."""
    rows = [["*" if m.current else "", m.entry.time, m.entry.app, m.entry.generation,
             m.entry.repository, m.entry.commit[:12], m.entry.result,
             m.entry.by.shown if m.entry.by is not None else "-",
             " ".join(f"{k}={v}" for k, v in sorted(m.entry.params.items())) or "-"]
            for m in made]
    header, *lines = columns(HISTORY_HEADER, [[printable(c) for c in r] for r in rows])
    sets = len({m.set for m in made}) < len(made)  # several apps: one apply, one set
    shown = [header]
    for before, m, line in zip([None, *made], made, lines):
        if sets and before is not None and before.set != m.set:
            shown.append("")  # the sets of apps, one block each
        shown.append(line)
    return shown


def cmd_sync(args: argparse.Namespace, layout: Layout) -> int:
    """Exit 0 when applied, with nothing to do, or offline; 1 when the pass failed (the
    running app untouched, the reason recorded)."""
    from reconciler.workflow.agent import one_pass, settings

    config = settings(layout, args.config)
    done = one_pass(_machine(args, layout), config, wait=args.wait, report=_terminal(args),
                    options=_options(args, keep_generations=args.keep_generations),
                    fetch_only=args.fetch_only, bundle=args.bundle)
    revision = done.revision[:12] if done.revision else "none"
    _say(args, f"Sync: {done.result} (revision {revision})"
         + (f": {done.reason}" if done.reason else ""), err=bool(done.code))
    if done.code and done.hint:
        _say(args, f"  hint: {done.hint}", err=True)
    return done.code


def cmd_agent(args: argparse.Namespace, layout: Layout) -> int:
    """SIGTERM (systemd stopping the agent) stops it between passes at once, and during a
    pass before the next step that is not part of a cutover: never mid-cutover."""
    from reconciler.workflow.agent import Agent, settings

    agent = Agent.following(_machine(args, layout), settings(layout, args.config),
                            options=_options(args), report=_agent_report)
    signal.signal(signal.SIGTERM, lambda signum, frame: agent.stop.set())
    return agent.run(once=args.once)


def cmd_ble(args: argparse.Namespace, layout: Layout) -> int:
    """Logs to stdout, a line each (systemd's journal adds the time); 0 when stopped,
    also by a stop that comes while the service still imports (kept until it runs)."""
    if args.ble_action is not None:
        return BLE_ACTIONS[args.ble_action](args)
    stopping = threading.Event()
    for number in (signal.SIGTERM, signal.SIGINT):
        signal.signal(number, lambda signum, frame: stopping.set())
    from reconciler.frontends.ble.serve import serve

    def log(line: str) -> None:
        print(printable(line), flush=True)

    from schemas.bluetooth import Writes

    return serve(_machine(args, layout), bus_address=args.bus, adapter=args.adapter, log=log,
                 bug=lambda: debug_log(layout), stopping=stopping, writes=Writes(args.writes))


def cmd_ble_pair(args: argparse.Namespace) -> int:
    """The window stays open `--seconds`; Ctrl-C or SIGTERM closes it early, as the timer
    does (exit 0: the person at the car ended it)."""
    from reconciler.workflow.bluetooth import pair

    stopping = threading.Event()
    for number in (signal.SIGTERM, signal.SIGINT):
        signal.signal(number, lambda signum, frame: stopping.set())
    phones: list[str] = []

    def opened() -> None:
        print(f"The car is pairable for {args.seconds} s ({args.adapter}): on the phone, "
              "open Privzone, choose CIRCLES and accept the pairing prompt. Ctrl-C closes "
              "the window early.", flush=True)

    def paired(phone: str) -> None:
        phones.append(phone)
        print(f"Paired: {printable(phone)}", flush=True)

    pair(bus_address=args.bus, adapter=args.adapter, seconds=args.seconds,
         stopped=stopping.is_set, opened=opened, paired=paired)
    print(f"Pairing window closed{' early' if stopping.is_set() else ''}: the car is not "
          f"pairable; {counted(len(phones), 'phone')} paired in it.")
    return EXIT_OK


def cmd_ble_phones(args: argparse.Namespace) -> int:
    from reconciler.workflow.bluetooth import bonded_phones

    found = bonded_phones(bus_address=args.bus, adapter=args.adapter)
    if not found:
        print(f"No phone is bonded with {args.adapter}: `lpam ble pair` lets one pair.")
        return EXIT_OK
    print("\n".join(columns(("Address", "Name", "Bonded"), [
        [p.address, printable(p.name or "-"), "yes" if p.bonded else "no (paired only)"]
        for p in found])))
    return EXIT_OK


def cmd_ble_forget(args: argparse.Namespace) -> int:
    from reconciler.workflow.bluetooth import forget_phone

    gone = forget_phone(bus_address=args.bus, adapter=args.adapter, address=args.address)
    name = f" ({printable(gone.name)})" if gone.name else ""
    print(f"Forgot {gone.address}{name}: its writes are refused until it pairs again.")
    return EXIT_OK


BLE_ACTIONS: dict[str, Callable[[argparse.Namespace], int]] = {
    "pair": cmd_ble_pair, "phones": cmd_ble_phones, "forget": cmd_ble_forget}


def cmd_install_ble(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.agent import install_ble

    command = [sys.executable, "-m", "reconciler", "--root", str(layout.root)]
    for path in install_ble(_machine(args, layout), command, report=_terminal(args),
                            writes=args.writes):
        print(f"Wrote {path}")
    print("The Bluetooth service answers the phone app (Privzone) as bluezone did; "
          "bluezone's own unit is stopped while it runs (Conflicts=).")
    return EXIT_OK


def cmd_install_agent(args: argparse.Namespace, layout: Layout) -> int:
    """The units run this very lpam (its interpreter, absolute) on this root."""
    from reconciler.workflow.agent import install_agent

    command = [sys.executable, "-m", "reconciler", "--root", str(layout.root)]
    written, config = install_agent(_machine(args, layout), command, config_file=args.config,
                                    report=_terminal(args))
    for path in written:
        print(f"Wrote {path}")
    print(f"The agent follows {config.source.url} ({config.source.branch}) every "
          f"{config.interval_seconds:g} s, and fetches at shutdown.")
    return EXIT_OK


def cmd_bundle(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.packing import make_bundle

    count = make_bundle(layout, args.out, url=args.source, branch=args.branch,
                        network_timeout=args.network_timeout, report=_terminal(args))
    print(f"Wrote {args.out}: the desired state and "
          f"{counted(count, 'repository', 'repositories')} it pins; on the "
          f"car: `lpam sync --bundle {args.out.name}`.")
    return EXIT_OK


def cmd_fleet(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow import fleet
    from reconciler.workflow.machine import now

    if args.action == "report":
        from reconciler.workflow.fleetreport import write_report

        written = write_report(args.repo, args.out, branch=args.branch, now=now())
        print(f"Wrote {written}: open it in a browser (no server needed), or publish the "
              "folder with your git host's pages.")
        return EXIT_OK
    tip, rows = fleet.read(args.repo, args.branch)
    at = now()  # the ages of the reports are measured against this machine's clock
    silent = fleet.silence(args.repo, tip)
    print(json.dumps(fleet.as_json(tip, rows, now=at, silent=silent), indent=2) if args.json
          else fleet.as_table(tip, rows, now=at, silent=silent))
    return EXIT_OK


def cmd_pin(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.pin import pin

    path = _desired_path(args, layout)
    done = pin(_machine(args, layout), path, report=_terminal(args), catalogs=args.catalogs,
               write=not args.dry_run, lock_timeout=args.lock_timeout)
    if not done:
        print(f"{path}: every repository is already pinned to a full commit.")
    elif args.dry_run:
        print(f"{path} was not changed (--dry-run).")
    else:
        print(f"Pinned {counted(len(done), 'repository', 'repositories')} in {path}; "
              "review and commit it.")
    return EXIT_OK


def _agent_report(event: Event) -> None:
    """The agent's events as log lines (its output goes to the journal)."""
    from reconciler.workflow.events import Fetched, Note, Planned, Progress

    if isinstance(event, (Note, Fetched)):
        print(f"note: {event.text}", flush=True)
    elif isinstance(event, Progress):
        print(event.text, flush=True)
    elif isinstance(event, Planned) and event.plan.steps:
        print(event.plan.summary, flush=True)


def cmd_services(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.machine import shutdown_services

    if shutdown_services(layout):
        print(f"Stopped the supervisord of {layout.root}; the apps it ran are stopped too.")
    else:
        print(f"No supervisord was running for {layout.root}.")
    return EXIT_OK


def cmd_status(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.report import status
    from reconciler.workflow.machine import Machine, services_for

    services = services_for(layout, args.services)
    Machine(layout, given_services=services).look()  # a crash, a power cut: on the timeline
    if args.json:
        calling: Calling = getattr(args, "calling", Calling())
        print(json.dumps(calling.spell_values(
            status.as_json(layout, state=services.state, manager=services.kind)), indent=2))
    else:
        _say(args, status.as_table(layout, state=services.state, manager=services.kind))
    return EXIT_OK


def cmd_validate(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.validation import Kind, validate

    _say(args, validate(Path(args.path), None if args.kind is None else Kind(args.kind)))
    return EXIT_OK


def cmd_import(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.importing import import_legacy

    text = import_legacy(layout, args.etc_dir, output=args.output)
    if args.output is None:
        print(text, end="")
    else:
        _say(args, f"Wrote {args.output}; review it, then "
             f"`lpam plan -f {shlex.quote(str(args.output))}`.")
    return EXIT_OK


def cmd_provenance(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.engine.records.timeline import Timeline
    from reconciler.workflow import provenance as prov

    if args.stamp:
        stamped = prov.stamp_finished(layout, now=time.time(), budget=prov.SCAN_LIMIT)
        print("\n".join(f"stamped {p}" for p in stamped) or "No finished data file needed "
              "a stamp.")
        return EXIT_OK
    car = prov.from_fleet(args.repo, args.vehicle) if args.repo is not None else \
        prov.known(Timeline(layout))
    if args.at is not None:
        answers = [prov.between(args.at, args.at, car)]
    elif args.between is not None:
        start, end = sorted(args.between)
        answers = [prov.between(start, end, car)]
    elif args.files:
        answers = [prov.of_file(path, car) for path in args.files]
    else:
        raise LpamError("give FILE…, --at TIME or --between T1 T2")
    if args.desired:
        return _print_desired(answers, car)
    if args.json:
        print(json.dumps([prov.as_json(a, car) for a in answers], indent=2))
    else:
        print("\n".join(line for a in answers for line in prov.describe(a, car)))
    if car.unreadable:
        print(f"note: {car.unreadable} line(s) of the timeline could not be read (torn by "
              "a power cut, or written by a newer lpam)", file=sys.stderr)
    large = Timeline(layout).size_warning() if args.repo is None else None
    if large:
        print(f"note: {large}", file=sys.stderr)
    return EXIT_OK


def _print_desired(answers: Sequence[Any], car: Any) -> int:
    from reconciler.workflow import provenance as prov

    found = [i for a in answers for i in a.found]
    if not found or any(a.verdict not in ("ran",) for a in answers):
        said = "; ".join(f"{a.verdict}: {a.said}" for a in answers if a.verdict != "ran")
        raise LpamError(f"no one software to reproduce: {said or 'nothing ran'}",
                         hint="ask for one moment with --at TIME")
    try:
        text, caveats = prov.desired_for(found, car)
    except ValueError as exc:
        raise LpamError(str(exc), hint="ask for one moment with --at TIME") from None
    print(text, end="")
    for caveat in caveats:
        print(f"note: {caveat}", file=sys.stderr)
    return EXIT_OK


COMMANDS = {
    "plan": cmd_plan,
    "apply": cmd_apply,
    "status": cmd_status,
    "validate": cmd_validate,
    "import-lpam": cmd_import,
    "provenance": cmd_provenance,
    "services": cmd_services,
    "sync": cmd_sync,
    "agent": cmd_agent,
    "install-agent": cmd_install_agent,
    "ble": cmd_ble,
    "install-ble": cmd_install_ble,
    "gates": cmd_gates,
    "pin": cmd_pin,
    "bundle": cmd_bundle,
    "fleet": cmd_fleet,
    "start": cmd_operate,
    "stop": cmd_operate,
    "restart": cmd_operate,
    "logs": cmd_logs,
    "history": cmd_history,
    "rollback": cmd_rollback,
}
