"""What each kind of step does.

An app is a service. A script app runs by its lifecycle scripts, and the unit its
`service` file names says whether it runs: a script's exit code is not trusted (the field's
scripts never use `set -e`), so after `start.sh` the app counts as running only when its
service manager says that unit is active, and after `stop.sh` only as stopped when the
unit is not. A scriptless app's unit is written by lpam and driven through the manager.
Either way, every script and unit runs in `/etc/libpanda.d/apps/<folder>`, the link to the
generation (reconciler/legacy/appdir.py), where the field's scripts expect it.

Repository steps are idempotent on their outcome (a checkout already at its commit is left
alone). Lifecycle steps write their *intent* to the state record before the script runs
(`starting` with the run's id) and the outcome after it (`running`): whatever kills lpam in
between, the next apply knows the app may be active, and — from the exit code the
script's guard leaves behind (reconciler/state.py settles it) — whether the script
finished, so a finished script is never run twice and a cut-off one is run again only
once it has certainly ended (the guard holds the apply lock until then).
"""

from __future__ import annotations

import getpass
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Literal

from reconciler import generations
from reconciler.errors import (
    DependencyError,
    GitError,
    HealthError,
    ServiceError,
    StepError,
    StoreDamagedError,
)
from reconciler.execution import cache
from reconciler.execution.context import Context
from reconciler.execution.supervision import await_unit, log_tail, runtime, settle, unit_for
from reconciler.generations import Generation
from reconciler.legacy import appdir
from reconciler.planning.model import GenerationKey, app_folder
from reconciler.unit import unit_name
from schemas.plan import Step, StepKind
from schemas.record import AppRecord, AppStatus, RepositoryRecord, Stray


def _arg(step: Step, name: str) -> str:
    value = step.args.get(name)
    if not isinstance(value, str):
        raise StepError(f"step {step.id} lacks {name}; the plan is malformed")
    return value


def _params(step: Step) -> dict[str, str]:
    value = step.args.get("params")
    return dict(value) if isinstance(value, dict) else {}


def checkout(step: Step, ctx: Context) -> None:
    check_out(step, ctx)
    record_checkout(step, ctx)


def check_out(step: Step, ctx: Context) -> None:
    """The checkout's work on its own repository, which touches nothing another
    repository's checkout does: the executor runs several at once (record_checkout after)."""
    key, url, commit = _arg(step, "key"), _arg(step, "url"), _arg(step, "commit")
    try:
        present = ctx.store.origin_url(key) == url and ctx.store.has_commit(key, commit)
    except StoreDamagedError as exc:  # since a saved plan was made: the store is a cache
        ctx.log(cache.renew(ctx.store, key, url, exc.damage))
        present = ctx.store.has_commit(key, commit)
    if not present:
        ctx.store.fetch(key, url)
    if ctx.store.head(key) != commit:
        ctx.store.checkout(key, commit)


def record_checkout(step: Step, ctx: Context) -> None:
    key, url, commit = _arg(step, "key"), _arg(step, "url"), _arg(step, "commit")
    ref = step.args.get("ref")
    before = ctx.record.repository(key)
    # what ran stays what ran until the apply succeeds (the same URL: the same repository)
    applied = before.applied if before is not None and before.url == url else None
    entry = RepositoryRecord(key=key, url=url, ref=ref if isinstance(ref, str) else None,
                             commit=commit, applied=applied)
    others = [r for r in ctx.record.repositories if r.key != key]
    ctx.save(ctx.record.model_copy(update={"repositories": sorted([*others, entry],
                                                                  key=lambda r: r.key)}))


def remove(step: Step, ctx: Context) -> None:
    key = _arg(step, "key")
    if ctx.layout.repository_dir(key).exists():
        ctx.store.remove(key)
    others = [r for r in ctx.record.repositories if r.key != key]
    ctx.save(ctx.record.model_copy(update={"repositories": others}))


def _optional(step: Step, name: str) -> str | None:
    value = step.args.get(name)
    return value if isinstance(value, str) else None


def _argv(step: Step, name: str) -> tuple[str, ...] | None:
    value = step.args.get(name)
    return tuple(value) if isinstance(value, list) else None


def _wanted(step: Step, ctx: Context) -> Generation:
    command, launch = _argv(step, "command"), _optional(step, "launch")
    path = _arg(step, "path")
    service = _optional(step, "service")
    if command is not None or launch is not None:
        service = unit_name(app_folder(path))
    pip = _argv(step, "pip")
    ros = step.args.get("ros")
    return Generation(
        app=_arg(step, "app"), generation=_arg(step, "generation"),
        repository=_arg(step, "repository"), commit=_arg(step, "commit"),
        path=path, tree=_arg(step, "tree"), params=_params(step),
        command=command, launch=launch, service=service,
        venv=str(ctx.dependencies().envs.location(pip)) if pip else None,
        ros=dict(ros) if isinstance(ros, dict) else {},
        ros_build=_optional(step, "build"), ros_workspace=_optional(step, "ros_workspace"),
        ros_user=_optional(step, "ros_user"),
    )


def apt(step: Step, ctx: Context) -> None:
    """Install the app's apt packages that are still missing, in one batch."""
    packages = ctx.dependencies().packages
    wanted = list(_argv(step, "packages") or ())
    _prepared(step, lambda: packages.install(packages.missing(wanted), log=ctx.log))


def pip(step: Step, ctx: Context) -> None:
    """The virtual environment of the app's requirements, created and completed."""
    envs = ctx.dependencies().envs
    _prepared(step, lambda: envs.ensure(list(_argv(step, "requirements") or ()), log=ctx.log))


def build(step: Step, ctx: Context) -> None:
    """The app's ROS repositories exported at their commits into a build space of their
    own, and built with catkin_make as the ROS user. A space that was built is reused."""
    key = _arg(step, "build")
    workspace = ctx.dependencies().workspace(Path(_arg(step, "workspace")), _arg(step, "user"))
    if workspace.built(key):
        return
    commits, keys, urls = (_mapping(step, name) for name in ("ros", "ros_keys", "ros_urls"))

    def work() -> None:
        src = workspace.prepare(key)
        for name, commit in sorted(commits.items()):
            if not ctx.store.has_commit(keys[name], commit):
                ctx.store.fetch(keys[name], urls[name])
            ctx.store.export_folder(keys[name], commit, "", src / name)
        workspace.build(key, log=ctx.log)

    _prepared(step, work)


def _prepared(step: Step, work: Callable[[], object]) -> None:
    """Run a preparation step's work; its errors name the app."""
    try:
        work()
    except (DependencyError, GitError) as exc:
        app = _arg(step, "app")
        message = exc.message if exc.message.startswith(app) else f"{app}: {exc.message}"
        raise DependencyError(message, hint=exc.hint, details=exc.details) from None


def _mapping(step: Step, name: str) -> dict[str, str]:
    value = step.args.get(name)
    if not isinstance(value, dict):
        raise StepError(f"step {step.id} lacks {name}; the plan is malformed")
    return dict(value)


def stage(step: Step, ctx: Context) -> None:
    """Copy the app folder at its commit into an immutable generation directory; for a
    scriptless app, have the service manager check the unit it will run (a unit that
    cannot run is refused now, while the old app still runs, not after it was stopped)."""
    gen = _wanted(step, ctx)
    folder = generations.stage(ctx.layout, ctx.store, gen)
    if gen.scriptless:
        try:
            ctx.services.check(unit_for(ctx, _record(gen, _optional(step, "user")), folder,
                                        runtime(ctx, gen)))
        except ServiceError as exc:
            raise StepError(f"{gen.app}: {exc.message}", hint=exc.hint) from None


def _record(gen: Generation, user: str | None) -> AppRecord:
    """The generation as the installed app it becomes (status: installed)."""
    return AppRecord(name=gen.app, repository=gen.repository, commit=gen.commit,
                     tree=gen.tree, path=gen.path, params=gen.params,
                     generation=gen.generation, service=gen.service,
                     command=None if gen.command is None else list(gen.command),
                     launch=gen.launch, user=user)


def _generation(ctx: Context, app: str, generation: str, fallback: Generation) -> Generation:
    meta = generations.read_meta(ctx.layout.generation_meta(app, generation))
    return meta if meta is not None else fallback


def _with_runtime(ctx: Context, gen: Generation) -> Generation:
    """`gen` as a step wants it, with the runtime its staging recorded when the step does
    not say (a rollback's steps come from the state record, which keeps no environment or
    ROS build: the generation's metadata does, so it returns to the build that worked)."""
    meta = generations.read_meta(ctx.layout.generation_meta(gen.app, gen.generation))
    if meta is None or gen.venv is not None or gen.ros_build is not None:
        return gen
    return replace(gen, venv=meta.venv, ros=meta.ros, ros_build=meta.ros_build,
                   ros_workspace=meta.ros_workspace, ros_user=meta.ros_user)


def _place(ctx: Context, gen: Generation) -> Path:
    """The generation's folder (restored from git first if it went missing), reachable at
    `/etc/libpanda.d/apps/<folder>`: that path, where the field's scripts expect it."""
    folder = generations.ensure(ctx.layout, ctx.store, gen)
    return appdir.point(ctx.layout, gen.folder, folder)


def _run(ctx: Context, gen: Generation, script: str, params: dict[str, str], run: str) -> None:
    """Run one script of `gen` in its place, in its runtime environment."""
    place = _place(ctx, gen)
    required = gen.scripts is not None and script in gen.scripts
    ctx.scripts.run(gen.app, place, script, {**params, **runtime(ctx, gen).environment},
                    run=run, required=required)


def _installed(step: Step, ctx: Context) -> AppRecord:
    app = ctx.record.app
    if app is None or app.name != _arg(step, "app") or app.generation != _arg(step, "generation"):
        raise StepError(
            f"step {step.id}: the state record no longer shows this app installed",
            hint="run `lpam plan` again; the machine changed during the apply",
        )
    return app


def _meta(ctx: Context, app: AppRecord) -> Generation:
    fallback = Generation(app=app.name, generation=app.generation, repository=app.repository,
                          commit=app.commit, path=app.path, tree=app.tree, params=app.params,
                          command=None if app.command is None else tuple(app.command),
                          launch=app.launch, service=app.service)
    return _generation(ctx, app.name, app.generation, fallback)


What = Literal["install", "start", "stop", "uninstall"]


def _lifecycle(ctx: Context, app: AppRecord, what: What, during: AppStatus,
               after: AppStatus | None) -> None:
    """Intent, work, outcome: the record never claims more than is known. The work is the
    app's script (then the unit it names is checked), or the unit lpam wrote for it."""
    run = ctx.run_id() if not app.scriptless else None
    ctx.save_app(app.model_copy(update={"status": during, "run": run}))
    gen = _meta(ctx, app)
    if app.scriptless:
        _unit_work(ctx, app, gen, what)
    else:
        assert run is not None
        _run(ctx, gen, f"{what}.sh", app.params, run)
        if app.service is not None and what in ("start", "stop"):
            try:
                await_unit(ctx, app.name, app.service, active=what == "start",
                       script=f"{what}.sh")
            except StepError:
                # The script ended with 0, but the unit says it did not do its work: the
                # record must not be settled from that exit code (reconciler/state.py).
                ctx.save_app(app.model_copy(update={"status": during, "run": None}))
                raise
    ctx.save_app(None if after is None else
                 app.model_copy(update={"status": after, "run": None}))


def _unit_work(ctx: Context, app: AppRecord, gen: Generation, what: What) -> None:
    """The lifecycle of a unit lpam writes: install writes it, uninstall removes it."""
    name = app.service or unit_name(gen.folder)
    if what == "install":
        ctx.services.install(unit_for(ctx, app, _place(ctx, gen), runtime(ctx, gen)))
    elif what == "start":
        ctx.services.start(name)
        await_unit(ctx, app.name, name, active=True, script=None)
    elif what == "stop":
        ctx.services.stop(name)
    else:
        ctx.services.uninstall(name)


def _stray(step: Step, ctx: Context) -> Stray | None:
    key = (_arg(step, "app"), _arg(step, "generation"))
    return next((s for s in ctx.record.strays if (s.name, s.generation) == key), None)


def _stray_script(ctx: Context, stray: Stray, what: Literal["stop", "uninstall"]) -> None:
    """Like `_lifecycle`, for an app found on disk: intent, script, outcome."""
    def replace(new: Stray | None) -> None:
        strays = [s for s in ctx.record.strays if s.generation != stray.generation
                  or s.name != stray.name]
        ctx.save(ctx.record.model_copy(update={"strays": strays + ([new] if new else [])}))

    run = ctx.run_id() if stray.service is None else None
    replace(stray.model_copy(update={"pending": what, "run": run}))
    if stray.folder is not None:  # an app LPAM installed: its own folder, its own scripts
        assert run is not None
        folder = ctx.layout.libpanda_apps / stray.folder
        ctx.scripts.run(stray.name, folder, f"{what}.sh", stray.params, run=run)
        unit = appdir.service_of(folder)
        if what == "stop" and unit is not None:  # its stop.sh's exit code is not trusted
            try:
                await_unit(ctx, stray.name, unit, active=False, script="stop.sh")
            except StepError:
                replace(stray.model_copy(update={"pending": what, "run": None}))
                raise
        if what == "uninstall":
            appdir.set_current(ctx.layout, None)
    elif stray.service is not None:
        if what == "stop":
            ctx.services.stop(stray.service)
        else:
            ctx.services.uninstall(stray.service)
    else:
        assert run is not None
        fallback = Generation(app=stray.name, generation=stray.generation, params=stray.params)
        gen = _generation(ctx, stray.name, stray.generation, fallback)
        _run(ctx, gen, f"{what}.sh", stray.params, run)
        if what == "uninstall":
            appdir.release(ctx.layout, gen.folder,
                           ctx.layout.generation_dir(gen.app, gen.generation))
    replace(None if what == "uninstall" else
            stray.model_copy(update={"stopped": True, "pending": None, "run": None}))


def stop(step: Step, ctx: Context) -> None:
    if step.args.get("stray"):
        stray = _stray(step, ctx)
        if stray is not None:
            _stray_script(ctx, stray, "stop")
        return
    _lifecycle(ctx, _installed(step, ctx), "stop", "stopping", "installed")


def uninstall(step: Step, ctx: Context) -> None:
    if step.args.get("stray"):
        stray = _stray(step, ctx)
        if stray is not None:
            _stray_script(ctx, stray, "uninstall")
        return
    # The generation stays until the apply succeeds: a failed cutover reinstalls it.
    app = _installed(step, ctx)
    _lifecycle(ctx, app, "uninstall", "uninstalling", None)
    appdir.release(ctx.layout, app_folder(app.path),
                   ctx.layout.generation_dir(app.name, app.generation))
    appdir.set_current(ctx.layout, None)


def install(step: Step, ctx: Context) -> None:
    gen = _with_runtime(ctx, _wanted(step, ctx))
    current = ctx.record.app
    redo = (current is not None and (current.name, current.generation) == (gen.app, gen.generation)
            and current.status in ("installing", "uninstalling"))
    if (current is not None and not redo) or ctx.record.strays:
        other = current.name if current is not None else ctx.record.strays[0].name
        raise StepError(
            f"refusing to install {gen.app}: {other} is still installed",
            hint="only one app may own the vehicle's CAN hardware; run `lpam plan` again",
        )
    if not ctx.layout.generation_dir(gen.app, gen.generation).is_dir():
        raise StepError(f"{gen.app}: generation {gen.generation} was not staged")
    app = _record(gen, _optional(step, "user")).model_copy(update={"good": _good(step)})
    appdir.set_current(ctx.layout, gen.folder)
    if gen.ros_build is not None and gen.ros_workspace is not None:
        # the field's scripts look for the sources in the workspace's own src/
        user = gen.ros_user or getpass.getuser()
        workspace = ctx.dependencies().workspace(Path(gen.ros_workspace), user)
        workspace.link(gen.ros_build, sorted(gen.ros))
    _lifecycle(ctx, app, "install", "installing", "installed")


def adopt(step: Step, ctx: Context) -> None:
    """LPAM's app is the desired one as it is: its record becomes lpam's (running if its
    unit ran), then its path leads to the generation staged from git (same files; LPAM's
    copy is moved aside, not deleted). No script runs: nothing that runs is touched."""
    gen = _wanted(step, ctx)
    folder = _arg(step, "folder")
    place = ctx.layout.generation_dir(gen.app, gen.generation)
    if not place.is_dir():
        raise StepError(f"{gen.app}: generation {gen.generation} was not staged")
    status: AppStatus = "running" if _optional(step, "running") == "yes" else "installed"
    app = _record(gen, _optional(step, "user")).model_copy(
        update={"status": status, "good": True})
    strays = [s for s in ctx.record.strays if s.folder != folder]
    ctx.save(ctx.record.model_copy(update={"app": app, "strays": strays}))
    appdir.point(ctx.layout, gen.folder, place)
    appdir.set_current(ctx.layout, gen.folder)


def configure(step: Step, ctx: Context) -> None:
    """New parameters (or user) for the installed generation; a unit lpam wrote is
    rewritten so that its next start has them."""
    app = _installed(step, ctx).model_copy(
        update={"params": _params(step), "user": _optional(step, "user"),
                "good": _good(step)})
    if app.scriptless and app.status not in ("installing", "uninstalling"):
        gen = _meta(ctx, app)
        ctx.services.install(unit_for(ctx, app, _place(ctx, gen), runtime(ctx, gen)))
    ctx.save_app(app)


def _good(step: Step) -> bool:
    """Whether the app counts as good once the step ends (planning/lifecycle.py decides:
    a generation proved good before, or an apply with nothing to check)."""
    return step.args.get("good") == "yes"


def start(step: Step, ctx: Context) -> None:
    app = _installed(step, ctx)
    good = app.good or _good(step)
    _lifecycle(ctx, app.model_copy(update={"held": False, "good": good}), "start", "starting",
               "running")


def verify(step: Step, ctx: Context) -> None:
    """The health check: the unit stays active `settle_seconds` without restarting, then
    `health.command` (when given) exits 0 within its timeout. HealthError rolls back."""
    app = _installed(step, ctx)
    health = step.args.get("health")
    settings = health if isinstance(health, dict) else {}
    seconds = float(settings.get("settle_seconds", "0"))
    timeout = float(settings.get("timeout_seconds", "10"))
    if app.service is not None and seconds > 0:
        settle(ctx, app, app.service, seconds)
    began = ctx.clock().timestamp() - seconds  # frames the app sent while it settled count
    command = _argv(step, "health_command")
    if command is not None:
        place = _place(ctx, _meta(ctx, app))
        ok, output = ctx.scripts.check(app.name, place, list(command), app.params,
                                       timeout=timeout)
        if not ok:
            raise HealthError(
                f"{app.name}: its health check `{' '.join(command)}` failed: {output}",
                hint="fix the app (or its health settings) and apply again",
                details=log_tail(ctx, app.service))
    _heard_on_bus(step, ctx, app, began)
    _proved(ctx, app)


def _heard_on_bus(step: Step, ctx: Context, app: AppRecord, began: float) -> None:
    """`health.can`: the app must put each of its ids on the bus; one missing fails health
    (and the apply rolls back). Read from the desired state's vehicle source."""
    can = step.args.get("health_can")
    if not isinstance(can, dict) or not can.get("ids"):
        return
    ids = [int(text, 16) for text in can["ids"].split()]
    within = float(can.get("within_seconds", "10"))
    if ctx.listener is None:
        raise HealthError(f"{app.name}: its health check needs the CAN bus, and this "
                          "command reads none", hint="apply the desired state that "
                          "declares the vehicle source")
    missing = sorted(set(ids) - ctx.listener.heard(ids, since=began, within=within))
    if missing:
        raise HealthError(
            f"{app.name}: did not put {', '.join(f'0x{i:X}' for i in missing)} on the CAN "
            f"bus within {within:g} s of starting",
            hint="check that the app talks to the bus (and the vehicle source lpam reads), "
            "or its health.can settings", details=log_tail(ctx, app.service))


def _proved(ctx: Context, app: AppRecord) -> None:
    """The health check ran to its end and passed: from now on the app is good (a
    rollback target, an apply that is `applied`). Nothing before this point may say so."""
    current = ctx.record.app
    if current is not None and (current.name, current.generation) == (app.name, app.generation):
        ctx.save_app(current.model_copy(update={"good": True}))


def prune(ctx: Context, *, keep: int = 3) -> None:
    """After a successful apply, generations still installed are kept (the app's and any
    stray's: their scripts are what stops them), and the last `keep` good ones of the
    history (what `lpam rollback` returns to); and only the exit codes still awaited."""
    record = ctx.record
    kept = {GenerationKey.of(s.name, s.generation) for s in record.strays}
    good = [GenerationKey.of(h.app, h.generation) for h in record.history
            if h.result == "applied"]
    kept.update(list(dict.fromkeys(reversed(good)))[:keep])
    if record.app is not None:
        kept.add(GenerationKey.of(record.app.name, record.app.generation))
    generations.prune(ctx.layout, kept)
    appdir.keep_offered(ctx.layout, ctx.store, record)
    _collect_dependencies(ctx)
    pending = {f"{r}.exit" for r in [record.app.run if record.app else None,
                                      *(s.run for s in record.strays)] if r}
    if ctx.layout.runs.is_dir():
        for result in ctx.layout.runs.iterdir():
            if result.name not in pending:
                result.unlink(missing_ok=True)


def _collect_dependencies(ctx: Context) -> None:
    """Virtual environments and ROS builds no kept generation runs with are removed; the
    ones kept are what `lpam rollback` returns to without a rebuild."""
    if ctx.deps is None:
        return
    kept = generations.installed_on_disk(ctx.layout)
    ctx.deps.envs.collect({Path(g.venv) for g in kept if g.venv is not None})
    builds: dict[tuple[str, str], set[str]] = {}
    for g in kept:
        if g.ros_workspace is not None and g.ros_build is not None:
            owner = (g.ros_workspace, g.ros_user or getpass.getuser())
            builds.setdefault(owner, set()).add(g.ros_build)
    for (path, user), keys in builds.items():
        ctx.deps.workspace(Path(path), user).collect(keys)


RUNNERS: dict[StepKind, Callable[[Step, Context], None]] = {
    StepKind.CHECKOUT: checkout,
    StepKind.APT: apt,
    StepKind.PIP: pip,
    StepKind.BUILD: build,
    StepKind.REMOVE: remove,
    StepKind.STAGE: stage,
    StepKind.STOP: stop,
    StepKind.UNINSTALL: uninstall,
    StepKind.INSTALL: install,
    StepKind.CONFIGURE: configure,
    StepKind.START: start,
    StepKind.VERIFY: verify,
    StepKind.ADOPT: adopt,
}
