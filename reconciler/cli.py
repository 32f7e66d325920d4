"""`lpam`: the only place that prints and exits.

Maps every LpamError to one short message (file:line:column for documents) and exit 1;
anything unexpected is a bug: its traceback goes to `<root>/var/log/lpam/debug.log`, and
the user gets one line pointing there. Heavy libraries (dulwich, networkx) are imported
only by the commands that need them, so `lpam --version` and `lpam status` start fast.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import signal
import sys
import traceback
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reconciler import __version__
from reconciler.errors import ConfigError, LpamError, Terminated
from reconciler.layout import Layout

if TYPE_CHECKING:  # imported lazily at run time: `lpam --version` must stay fast
    from reconciler.execution.ports import Gate, Services
    from reconciler.workflow.events import Event
    from reconciler.workflow.machine import Machine
    from schemas.desired import DesiredState
    from schemas.plan import Plan

EXIT_OK, EXIT_ERROR, EXIT_CHANGES = 0, 1, 2
NETWORK_TIMEOUT = ("--network-timeout",)
NETWORK_TIMEOUT_OPTIONS: dict[str, Any] = {
    "type": float, "default": 60.0, "metavar": "SECONDS",
    "help": "give up on a git server that does not answer for this long (default 60)",
}
SERVICES = ("--services",)
SERVICES_OPTIONS: dict[str, Any] = {
    "choices": ("systemd", "supervisor"), "default": None,
    "help": "service manager that runs the app (default: $LPAM_SERVICES, else systemd "
    "where it runs, else supervisord)",
}
LOCK_TIMEOUT = ("--lock-timeout",)
LOCK_TIMEOUT_OPTIONS: dict[str, Any] = {
    "type": float, "default": 10.0, "metavar": "SECONDS",
    "help": "wait this long for a running apply to finish (default 10)",
}


def now() -> datetime:
    return datetime.now(timezone.utc)


def services_for(layout: Layout, override: str | None) -> Services:
    from reconciler.workflow.machine import services_for as choose

    return choose(layout, override)


WAIT = ("--wait",)
WAIT_OPTIONS: dict[str, Any] = {
    "type": float, "default": 0.0, "metavar": "SECONDS",
    "help": "wait up to SECONDS for closed update gates to open before the cutover; still "
            "closed: exit 75, deferred (default 0)"}
VALIDATE_KINDS = ("desired-state", "catalog", "repository", "agent", "plan")
"""The values of reconciler.validation.Kind, spelled out: the parser is built before any
command runs, and `lpam --version` must not import the schemas."""
FORCE = ("--force",)
FORCE_OPTIONS: dict[str, Any] = {
    "action": "store_true", "help": "ignore the update gates (the vehicle may be moving)"}


def _parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--root", default=argparse.SUPPRESS,
        help="put every path lpam touches under ROOT (default: $LPAM_ROOT or /)",
    )
    parser = argparse.ArgumentParser(
        prog="lpam", parents=[common],
        description="Make this vehicle's apps match a declared desired state.",
    )
    parser.add_argument("--version", action="version", version=f"lpam {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    plan = sub.add_parser("plan", parents=[common], help="show what apply would change")
    plan.add_argument("-f", "--file", type=Path, help="desired state (default: under --root)")
    plan.add_argument("--json", action="store_true", help="print the plan as JSON")
    plan.add_argument("-o", "--out", type=Path, help="save the plan for `lpam apply PLANFILE`")
    plan.add_argument("--detailed-exitcode", action="store_true",
                      help="exit 0 without changes, 2 with changes, 1 on error")
    plan.add_argument("--offline", action="store_true",
                      help="use no network: plan from what the last fetch brought")
    plan.add_argument(*LOCK_TIMEOUT, **LOCK_TIMEOUT_OPTIONS)
    plan.add_argument(*NETWORK_TIMEOUT, **NETWORK_TIMEOUT_OPTIONS)
    plan.add_argument(*SERVICES, **SERVICES_OPTIONS)

    apply = sub.add_parser("apply", parents=[common], help="make the machine match")
    apply.add_argument("planfile", nargs="?", type=Path, help="a plan saved by plan --out")
    apply.add_argument("-f", "--file", type=Path, help="desired state (default: under --root)")
    apply.add_argument("--yes", action="store_true", help="apply without asking")
    apply.add_argument(*LOCK_TIMEOUT, **LOCK_TIMEOUT_OPTIONS)
    apply.add_argument("--script-timeout", type=float, default=600.0, metavar="SECONDS",
                       help="kill an app script running longer than this (default 600)")
    apply.add_argument(*NETWORK_TIMEOUT, **NETWORK_TIMEOUT_OPTIONS)
    apply.add_argument(*SERVICES, **SERVICES_OPTIONS)
    apply.add_argument("--keep-generations", type=_at_least_one, default=3, metavar="N",
                       help="good generations kept on disk for `lpam rollback` (default 3)")
    apply.add_argument("--release", action="store_true",
                       help="end a rollback's hold and apply the desired state again")
    apply.add_argument(*WAIT, **WAIT_OPTIONS)

    status = sub.add_parser("status", parents=[common], help="show repositories and apps")
    status.add_argument("--json", action="store_true")
    status.add_argument(*SERVICES, **SERVICES_OPTIONS)

    for action, what in (("start", "start the installed app now (ends an operator stop)"),
                         ("stop", "stop the installed app; it stays stopped until `lpam "
                          "start` or a change of the desired state"),
                         ("restart", "stop and start the installed app")):
        op = sub.add_parser(action, parents=[common], help=what)
        op.add_argument("-f", "--file", type=Path,
                        help="desired state whose update gates apply (default: under --root)")
        op.add_argument(*WAIT, **WAIT_OPTIONS)
        op.add_argument(*FORCE, **FORCE_OPTIONS)
        op.add_argument(*LOCK_TIMEOUT, **LOCK_TIMEOUT_OPTIONS)
        op.add_argument(*SERVICES, **SERVICES_OPTIONS)
        op.add_argument("--script-timeout", type=float, default=600.0, metavar="SECONDS",
                        help="kill an app script running longer than this (default 600)")

    logs = sub.add_parser("logs", parents=[common], help="the installed app's recent output")
    logs.add_argument("-n", "--lines", type=int, default=50, help="how many lines (default 50)")
    logs.add_argument("-f", "--follow", action="store_true", help="keep printing new output")
    logs.add_argument(*SERVICES, **SERVICES_OPTIONS)

    history = sub.add_parser("history", parents=[common],
                             help="the generations made current, newest last")
    history.add_argument("--json", action="store_true")

    rollback = sub.add_parser("rollback", parents=[common],
                              help="make the previous good generation current again, offline")
    rollback.add_argument("-f", "--file", type=Path,
                          help="desired state the rollback holds against (default: under --root)")
    rollback.add_argument("--yes", action="store_true", help="roll back without asking")
    rollback.add_argument(*WAIT, **WAIT_OPTIONS)
    rollback.add_argument(*FORCE, **FORCE_OPTIONS)
    rollback.add_argument(*LOCK_TIMEOUT, **LOCK_TIMEOUT_OPTIONS)
    rollback.add_argument(*SERVICES, **SERVICES_OPTIONS)
    rollback.add_argument("--script-timeout", type=float, default=600.0, metavar="SECONDS",
                          help="kill an app script running longer than this (default 600)")

    sync = sub.add_parser("sync", parents=[common],
                          help="one pass of following the desired-state repository")
    sync.add_argument("--config", type=Path, help="agent.yaml (default: under --root)")
    sync.add_argument("--fetch-only", action="store_true",
                      help="fetch the source and what it pins, record, change nothing")
    sync.add_argument("--bundle", type=Path, metavar="FILE",
                      help="take the source and what it pins from a bundle: no network")
    sync.add_argument(*LOCK_TIMEOUT, **LOCK_TIMEOUT_OPTIONS)
    sync.add_argument(*NETWORK_TIMEOUT, **NETWORK_TIMEOUT_OPTIONS)
    sync.add_argument(*SERVICES, **SERVICES_OPTIONS)
    sync.add_argument("--script-timeout", type=float, default=600.0, metavar="SECONDS",
                      help="kill an app script running longer than this (default 600)")
    sync.add_argument("--keep-generations", type=_at_least_one, default=3, metavar="N",
                      help="good generations kept on disk for `lpam rollback` (default 3)")
    sync.add_argument("--wait", type=float, default=None, metavar="SECONDS",
                      help="wait up to SECONDS for closed update gates (default: agent.yaml's "
                      "gate_wait_seconds)")

    agent = sub.add_parser("agent", parents=[common],
                           help="follow the desired-state repository: sync passes forever")
    agent.add_argument("--config", type=Path, help="agent.yaml (default: under --root)")
    agent.add_argument("--once", action="store_true", help="one pass, then exit with its code")
    agent.add_argument(*NETWORK_TIMEOUT, **NETWORK_TIMEOUT_OPTIONS)
    agent.add_argument(*SERVICES, **SERVICES_OPTIONS)
    agent.add_argument("--script-timeout", type=float, default=600.0, metavar="SECONDS",
                       help="kill an app script running longer than this (default 600)")
    agent.add_argument(*LOCK_TIMEOUT, **LOCK_TIMEOUT_OPTIONS)

    gates = sub.add_parser("gates", parents=[common],
                           help="the update gates now: speed, locks, time window")
    gates.add_argument("-f", "--file", type=Path, help="desired state (default: under --root)")
    gates.add_argument("--json", action="store_true")

    install = sub.add_parser("install-agent", parents=[common],
                             help="install the systemd units that run the agent on this car")
    install.add_argument("--config", type=Path, help="agent.yaml (default: under --root)")
    install.add_argument(*SERVICES, **SERVICES_OPTIONS)

    bundle = sub.add_parser("bundle", parents=[common],
                            help="offline bundles of the desired state and what it pins")
    bundle.add_argument("action", choices=("create",))
    bundle.add_argument("out", type=Path, help="the bundle file to write")
    bundle.add_argument("--source", help="desired-state repository (default: agent.yaml's)")
    bundle.add_argument("--branch", help="its branch (default: agent.yaml's, else main)")
    bundle.add_argument(*NETWORK_TIMEOUT, **NETWORK_TIMEOUT_OPTIONS)

    fleet = sub.add_parser("fleet", parents=[common],
                           help="the fleet's status, read from a clone of its repository")
    fleet.add_argument("action", choices=("status",))
    fleet.add_argument("--repo", type=Path, default=Path("."),
                       help="a clone of the desired-state repository (default: here)")
    fleet.add_argument("--branch", default="main", help="the branch the cars follow")
    fleet.add_argument("--json", action="store_true")

    pin = sub.add_parser("pin", parents=[common],
                         help="pin every branch or tag of a desired state to its commit now")
    pin.add_argument("file", nargs="?", type=Path, help="desired state (default: under --root)")
    pin.add_argument("--catalogs", action="store_true",
                     help="also report the ROS repositories of the app it names")
    pin.add_argument("--dry-run", action="store_true", help="say what would change only")
    pin.add_argument(*NETWORK_TIMEOUT, **NETWORK_TIMEOUT_OPTIONS)

    services = sub.add_parser("services", parents=[common],
                              help="the service manager lpam started (supervisord)")
    services.add_argument("action", choices=("shutdown",),
                          help="shutdown: stop the supervisord lpam started for this root")

    validate = sub.add_parser("validate", parents=[common],
                              help="check any document lpam reads, by the kind its keys show")
    validate.add_argument("path", type=Path)
    validate.add_argument("--kind", choices=VALIDATE_KINDS,
                          help="read PATH as this kind instead of deciding from its keys")

    imp = sub.add_parser("import-lpam", parents=[common],
                         help="write a desired state equivalent to an LPAM installation")
    imp.add_argument("etc_dir", nargs="?", type=Path,
                     help="LPAM's folder (default: <root>/etc/libpanda.d)")
    imp.add_argument("-o", "--output", type=Path, help="write here instead of printing")
    return parser


def _at_least_one(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError("keep at least 1 (the installed generation)")
    return value


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


def _terminate(signum: int, frame: object) -> None:
    raise Terminated


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    signal.signal(signal.SIGTERM, _terminate)
    layout = _layout(args)
    try:
        return int(COMMANDS[args.command](args, layout))
    except LpamError as exc:
        print(exc.render(), file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:  # `lpam plan | head`: the reader left; nothing more to say
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except (KeyboardInterrupt, Terminated) as exc:
        if args.command in CHANGES_THE_CAR:
            print("interrupted: lpam recorded where it stood (a script under way is stopped "
                  f"with its whole process group); run `{again(args)}` to resume",
                  file=sys.stderr)
        else:
            print("interrupted: nothing was changed", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    except Exception:  # a bug: keep the traceback away from the user, but keep it
        log = _debug_log(layout)
        print(f"error: internal error in lpam {__version__}; details in {log}", file=sys.stderr)
        return EXIT_ERROR


CHANGES_THE_CAR = ("apply", "sync", "agent", "start", "stop", "restart", "rollback")


def again(args: argparse.Namespace) -> str:
    """The command that goes on from where this one stopped, as the user would type it:
    the same root and desired-state file (a saved plan is stale once part of it ran)."""
    import shlex

    parts = ["lpam"]
    root = getattr(args, "root", None)
    if root:
        parts += ["--root", str(root)]
    parts.append(args.command if args.command != "agent" else "sync")
    if getattr(args, "file", None) is not None:
        parts += ["-f", str(args.file)]
    if getattr(args, "config", None) is not None:
        parts += ["--config", str(args.config)]
    return shlex.join(parts)


def _debug_log(layout: Layout) -> str:
    """Append the traceback to lpam's debug log, never through a planted link."""
    from reconciler.reading import open_append

    try:
        fd = open_append(layout.debug_log)
    except (OSError, LpamError):
        return "(the debug log could not be written)"
    try:
        text = f"--- {now().isoformat()} lpam {__version__} {sys.argv}\n" + traceback.format_exc()
        os.write(fd, text.encode("utf-8", "replace"))
    except OSError:
        return "(the debug log could not be written)"
    finally:
        os.close(fd)
    return str(layout.debug_log)


def _desired_path(args: argparse.Namespace, layout: Layout) -> Path:
    return Path(args.file) if args.file else layout.desired_state


def _machine(args: argparse.Namespace, layout: Layout) -> Machine:
    from reconciler.workflow.machine import Machine

    return Machine.at(layout, services=getattr(args, "services", None),
                      network_timeout=getattr(args, "network_timeout", 60.0))


class Terminal:
    """Where the use cases' events go in a terminal: notes to stderr, progress to stdout,
    and of a long command's output (a build, an install) its command line, then at most
    every few seconds how long it has run and its latest line."""

    EVERY = 5.0

    def __init__(self) -> None:
        import time

        self._clock = time.monotonic
        self._started = self._shown = self._clock()

    def __call__(self, event: Event) -> None:
        from reconciler.planning.render import render
        from reconciler.workflow.events import Note, Output, Planned, Progress

        if isinstance(event, Note):
            print(f"note: {event.text}", file=sys.stderr)
        elif isinstance(event, Progress):
            print(event.text, flush=True)
        elif isinstance(event, Planned):
            print(render(event.plan))
        elif isinstance(event, Output):
            self._output(event.line)

    def _output(self, line: str) -> None:
        now_ = self._clock()
        if line.startswith("$ "):  # a new command: its clock starts
            self._started = self._shown = now_
            print(f"      {_fit(line, 100)}", flush=True)
        elif now_ - self._shown >= self.EVERY:
            self._shown = now_
            print(f"      … {now_ - self._started:.0f} s: {_fit(line, 80)}", flush=True)


def _fit(line: str, width: int) -> str:
    """`line` in at most `width` printable characters, cut in the middle: the end of a
    command line (the path, the package) is the part that says most."""
    text = "".join(c if c.isprintable() else "?" for c in line)
    if len(text) <= width:
        return text
    head = width * 2 // 5
    return f"{text[:head]} … {text[len(text) - (width - head - 3):]}"


def cmd_plan(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.documents import load_desired
    from reconciler.workflow.planning import plan

    path = _desired_path(args, layout)
    desired = load_desired(path)
    made = plan(_machine(args, layout), path, desired, report=Terminal(),
                offline=args.offline, out=args.out, lock_timeout=args.lock_timeout)
    return _show_plan(args, made)


def _show_plan(args: argparse.Namespace, plan: Plan) -> int:
    from reconciler.planning.render import render

    if args.json:
        print(plan.model_dump_json(indent=2))
    else:
        print(render(plan))
        if args.out is not None:
            print(f"\nSaved the plan to {args.out}; apply it with `lpam apply {args.out}`.")
    if args.detailed_exitcode and plan.has_changes:
        return EXIT_CHANGES
    return EXIT_OK


def cmd_apply(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.documents import load_desired, load_plan
    from reconciler.workflow.applying import ApplyOptions, apply, apply_saved

    if args.planfile is not None and args.file is not None:
        raise LpamError("give either a plan file or -f FILE, not both")
    options = ApplyOptions(lock_timeout=args.lock_timeout, script_timeout=args.script_timeout,
                           keep_generations=args.keep_generations, release=args.release,
                           wait=args.wait, resume=again(args))
    # Bad input is rejected before the lock is taken, so it never waits on another apply.
    if args.planfile is not None:
        saved = load_plan(args.planfile)
        machine = _machine(args, layout)
        found = _desired_if_any(args, layout, machine)
        base = found[2] if found else layout.root
        print()
        done = apply_saved(machine, saved, str(args.planfile), options=options,
                           report=Terminal(),
                           gate=machine.gate_for(found[1], base) if found else None,
                           listener=machine.listener_for(found[1], base) if found else None)
    else:
        path = _desired_path(args, layout)
        machine = _machine(args, layout)
        machine.warm_network()
        desired = load_desired(path)
        done = apply(machine, path, desired, options=options,
                     confirm=lambda plan: _confirm(args), report=Terminal())
    if done.cancelled:
        print("Apply cancelled; nothing was changed.")
        return EXIT_ERROR
    if done.steps:
        print(f"\nApply complete: {done.steps} steps; {done.app}. Script output: {done.log}")
    return EXIT_OK


def _confirm(args: argparse.Namespace) -> bool:
    if not args.yes:
        if not sys.stdin.isatty():
            raise LpamError("apply needs confirmation", hint="pass --yes to apply without asking")
        if input("\nApply these changes? Only 'yes' is accepted: ").strip() != "yes":
            return False
    print()
    return True


def cmd_operate(args: argparse.Namespace, layout: Layout) -> int:
    """`lpam start|stop|restart`: on the installed app now, journalled like an apply."""
    from reconciler.execution.lock import apply_lock
    from reconciler.workflow.operate import operate

    machine = _machine(args, layout)
    gate = _gate(args, layout, machine)
    with apply_lock(layout, timeout=args.lock_timeout) as lock:
        ctx, _ = machine.context(machine.store(), lock, command=args.command,
                                 script_timeout=args.script_timeout, report=Terminal(),
                                 gate=gate, gate_wait=args.wait)
        print(operate(ctx, args.command, progress=print))
    return EXIT_OK


def _gate(args: argparse.Namespace, layout: Layout, machine: Machine) -> Gate | None:
    """The update gates operator commands obey, unless `--force`: those of `-f FILE`, else
    of the default desired state, else of the one the agent last applied."""
    if getattr(args, "force", False):
        return None
    found = _desired_if_any(args, layout, machine)
    return machine.gate_for(found[1], found[2]) if found else None


def _desired_if_any(args: argparse.Namespace, layout: Layout,
                    machine: Machine) -> tuple[Path, DesiredState, Path] | None:
    """The desired state in force (see `_gate`), for its gates and vehicle source; one that
    cannot be read leaves the gates unknown, which is refused rather than guessed."""
    from reconciler.documents import load_desired
    from reconciler.workflow.sync import applied_desired

    path = _desired_path(args, layout)
    try:
        if path.exists():
            return path, load_desired(path), path.resolve().parent
        followed = None if args.file else applied_desired(machine)
        return None if followed is None else \
            (followed.label, followed.desired, followed.base_dir)
    except LpamError as exc:  # raised as it is, so a document's file:line:col stays
        exc.hint = ((exc.hint + "; ") if exc.hint else "") + (
            "the update gates cannot be known: fix it, or pass --force to ignore them "
            "(the vehicle may be moving)")
        raise


def cmd_gates(args: argparse.Namespace, layout: Layout) -> int:
    """Each update gate now. Exit 0 when all are open, 75 when a cutover would be deferred."""
    from reconciler.documents import load_desired
    from reconciler.errors import Deferred

    path = _desired_path(args, layout)
    desired = load_desired(path)
    gate = _machine(args, layout).gate_for(desired, path.resolve().parent)
    states = list(gate.states()) if gate is not None else []
    is_open = all(s.open for s in states)
    if args.json:
        print(json.dumps({"desired_state": str(path), "gated": gate is not None,
                          "open": is_open, "gates": [
                              {"name": s.name, "open": s.open, "detail": s.detail}
                              for s in states]}, indent=2))
    elif gate is None:
        print(f"No update gates: {path} has no `gates:`; a cutover may happen at any moment.")
    else:
        print(f"Update gates of {path}:")
        for s in states:
            print(f"  {s.name:<8} {'open' if s.open else 'CLOSED':<7} {s.detail}")
        print("A cutover may happen now." if is_open else
              "A cutover now would be deferred (exit 75).")
    return EXIT_OK if is_open else Deferred.exit_code


def cmd_logs(args: argparse.Namespace, layout: Layout) -> int:
    """The installed app's output (reconciler/workflow/logs.py says from where)."""
    import time

    from reconciler.workflow.logs import app_logs

    machine = _machine(args, layout)
    shown = app_logs(machine, max(args.lines, 1))
    for note in shown.notes:
        print(f"note: {note}", file=sys.stderr)
    for line in shown.lines:
        print(line)
    if args.follow and shown.unit is None:
        raise LpamError("cannot follow: the service manager does not have this app's output",
                        hint="the note above says where it is")
    previous = shown.lines
    while args.follow and shown.unit is not None:
        time.sleep(1.0)
        lines = machine.services.logs(shown.unit, 200)
        for line in lines[_overlap(previous, lines):]:
            print(line, flush=True)
        previous = lines
    return EXIT_OK


def _overlap(before: list[str], after: list[str]) -> int:
    """How many leading lines of `after` were the end of `before` (what -f already printed)."""
    for size in range(min(len(before), len(after)), 0, -1):
        if before[-size:] == after[:size]:
            return size
    return 0


def cmd_history(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.state import read_record

    record = read_record(layout)
    if args.json:
        print(json.dumps([h.model_dump(mode="json") for h in record.history], indent=2))
        return EXIT_OK
    if not record.history:
        print("No history yet: no apply has made an app current.")
        return EXIT_OK
    current = record.app
    for h in record.history:
        mark = "*" if current is not None and (h.generation, h.params) == (
            current.generation, current.params) and h.result == "applied" else " "
        params = " ".join(f"{k}={v}" for k, v in sorted(h.params.items())) or "-"
        print(f"{mark} {h.time}  {h.app:<20} {h.generation}  {h.repository}@{h.commit[:12]}  "
              f"{h.result:<11}  {params}")
    return EXIT_OK


def cmd_rollback(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.documents import load_desired
    from reconciler.execution.lock import apply_lock
    from reconciler.workflow.operate import previous_good, rollback

    path = _desired_path(args, layout)
    desired = load_desired(path) if path.exists() else None
    machine = _machine(args, layout)
    gate = _gate(args, layout, machine)
    with apply_lock(layout, timeout=args.lock_timeout) as lock:
        ctx, _ = machine.context(machine.store(), lock, command=args.command,
                                 script_timeout=args.script_timeout, report=Terminal(),
                                 gate=gate, gate_wait=args.wait)
        entry = previous_good(ctx)
        print(f"Roll back to {entry.app} ({entry.generation}, commit {entry.commit[:12]}, "
              f"applied {entry.time})?")
        if not args.yes:
            if not sys.stdin.isatty():
                raise LpamError("rollback needs confirmation",
                                hint="pass --yes to roll back without asking")
            if input("Only 'yes' is accepted: ").strip() != "yes":
                print("Rollback cancelled; nothing was changed.")
                return EXIT_ERROR
        print(rollback(ctx, entry, desired, progress=print))
    return EXIT_OK


def cmd_sync(args: argparse.Namespace, layout: Layout) -> int:
    """Exit 0 when applied, with nothing to do, or offline; 1 when the pass failed (the
    running app untouched, the reason recorded)."""
    from reconciler.documents import load_agent
    from reconciler.workflow.applying import ApplyOptions
    from reconciler.workflow.sync import sync

    config = load_agent(args.config if args.config is not None else layout.agent_config)
    wait = config.gate_wait_seconds if args.wait is None else args.wait
    options = ApplyOptions(lock_timeout=args.lock_timeout, script_timeout=args.script_timeout,
                           keep_generations=args.keep_generations, wait=wait,
                           resume=again(args))
    done = sync(_machine(args, layout), config, report=Terminal(), options=options,
                fetch_only=args.fetch_only, bundle=args.bundle)
    revision = done.revision[:12] if done.revision else "none"
    print(f"Sync: {done.result} (revision {revision})"
          + (f": {done.reason}" if done.reason else ""),
          file=sys.stderr if done.code else sys.stdout)
    if done.code and done.hint:
        print(f"  hint: {done.hint}", file=sys.stderr)
    return done.code


def cmd_agent(args: argparse.Namespace, layout: Layout) -> int:
    """SIGTERM (systemd stopping the agent) stops it between passes at once, and during a
    pass before the next step that is not part of a cutover: never mid-cutover."""
    from reconciler.documents import load_agent
    from reconciler.workflow.agent import Agent
    from reconciler.workflow.applying import ApplyOptions

    config = load_agent(args.config if args.config is not None else layout.agent_config)
    options = ApplyOptions(lock_timeout=args.lock_timeout, script_timeout=args.script_timeout,
                           wait=config.gate_wait_seconds, resume=again(args))
    agent = Agent(_machine(args, layout), config, report=_agent_report, options=options)
    signal.signal(signal.SIGTERM, lambda signum, frame: agent.stop.set())
    return agent.run(once=args.once)


def cmd_install_agent(args: argparse.Namespace, layout: Layout) -> int:
    """The units run this very lpam (its interpreter, absolute) on this root; agent.yaml
    must be valid first, so a car is never set to follow a source it cannot read."""
    from reconciler.documents import load_agent
    from reconciler.workflow.agent import install_agent

    config_path = args.config if args.config is not None else layout.agent_config
    config = load_agent(config_path)
    command = [sys.executable, "-m", "reconciler", "--root", str(layout.root)]
    other = str(config_path.resolve()) if args.config is not None else None
    for path in install_agent(_machine(args, layout), command, config=other,
                              report=Terminal()):
        print(f"Wrote {path}")
    print(f"The agent follows {config.source.url} ({config.source.branch}) every "
          f"{config.interval_seconds:g} s, and fetches at shutdown.")
    return EXIT_OK


def cmd_bundle(args: argparse.Namespace, layout: Layout) -> int:
    """Made under a temporary root of its own: a laptop needs no lpam installation."""
    import tempfile

    from reconciler.workflow.bundle import create

    url, branch = args.source, args.branch
    if url is None or branch is None:
        from reconciler.documents import load_agent

        if url is None and not layout.agent_config.exists():
            raise LpamError("which desired-state repository?",
                            hint="pass --source URL (or run where agent.yaml names it)")
        if layout.agent_config.exists():
            config = load_agent(layout.agent_config)
            url = url or config.source.url
            branch = branch or config.source.branch
    with tempfile.TemporaryDirectory(prefix="lpam-bundle-root-") as tmp:
        from reconciler.workflow.machine import Machine

        machine = Machine.at(Layout(Path(tmp)), network_timeout=args.network_timeout)
        count = create(machine, url, branch or "main", args.out, report=Terminal())
    print(f"Wrote {args.out}: the desired state and {count} repositories it pins; on the "
          f"car: `lpam sync --bundle {args.out.name}`.")
    return EXIT_OK


def cmd_fleet(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow import fleet

    tip, rows = fleet.read(args.repo, args.branch)
    at = now()  # the ages of the reports are measured against this machine's clock
    print(json.dumps(fleet.as_json(tip, rows, now=at), indent=2) if args.json
          else fleet.as_table(tip, rows, now=at))
    return EXIT_OK


def cmd_pin(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.workflow.pin import pin

    path = args.file if args.file is not None else layout.desired_state
    done = pin(_machine(args, layout), path, report=Terminal(), catalogs=args.catalogs,
               write=not args.dry_run)
    if not done:
        print(f"{path}: every repository is already pinned to a full commit.")
    elif args.dry_run:
        print(f"{path} was not changed (--dry-run).")
    else:
        print(f"Pinned {len(done)} repositories in {path}; review and commit it.")
    return EXIT_OK


def _agent_report(event: Event) -> None:
    """The agent's events as log lines (its output goes to the journal)."""
    from reconciler.workflow.events import Note, Planned, Progress

    if isinstance(event, Note):
        print(f"note: {event.text}", flush=True)
    elif isinstance(event, Progress):
        print(event.text, flush=True)
    elif isinstance(event, Planned) and event.plan.steps:
        print(event.plan.summary, flush=True)


def cmd_services(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.adapters.services.supervisor import shutdown

    if shutdown(layout):
        print(f"Stopped the supervisord of {layout.root}; the apps it ran are stopped too.")
    else:
        print(f"No supervisord was running for {layout.root}.")
    return EXIT_OK


def cmd_status(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler import status

    services = services_for(layout, args.services)
    if args.json:
        print(json.dumps(status.as_json(layout, state=services.state, manager=services.kind),
                         indent=2))
    else:
        print(status.as_table(layout, state=services.state, manager=services.kind))
    return EXIT_OK


def cmd_validate(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.validation import Kind, validate

    print(validate(Path(args.path), None if args.kind is None else Kind(args.kind)))
    return EXIT_OK


def cmd_import(args: argparse.Namespace, layout: Layout) -> int:
    from reconciler.legacy import import_lpam

    etc_dir = args.etc_dir if args.etc_dir is not None else layout.root / "etc" / "libpanda.d"
    text = import_lpam(etc_dir)
    if args.output is None:
        print(text, end="")
        return EXIT_OK
    from reconciler.atomic import write_atomic

    if args.output.exists():
        raise ConfigError("already exists; lpam will not overwrite it", path=args.output,
                          hint="choose another -o FILE or move the existing file away")
    write_atomic(args.output, text)
    print(f"Wrote {args.output}; review it, then `lpam plan -f {args.output}`.")
    return EXIT_OK


COMMANDS = {
    "plan": cmd_plan,
    "apply": cmd_apply,
    "status": cmd_status,
    "validate": cmd_validate,
    "import-lpam": cmd_import,
    "services": cmd_services,
    "sync": cmd_sync,
    "agent": cmd_agent,
    "install-agent": cmd_install_agent,
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
