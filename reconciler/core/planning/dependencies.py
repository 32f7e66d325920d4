"""The desired app's dependencies in the plan: what is missing, and the steps that prepare it.

Every one of them is prepared before the cutover (LPAM installed them after stopping the
old app, so a failed `pip install` or `catkin_make` left the car with no app): apt packages
dpkg lacks, the virtual environment of the app's pip requirements, and the catkin build of
its ROS repositories at their commits. Each is decided from what the machine has now
(`DepsObserved`), so an apply that changes only parameters, or nothing, runs none of them.
"""

from __future__ import annotations

from reconciler.core.planning.lifecycle import step_id
from reconciler.core.planning.model import UNKNOWN, AppTarget, DepsObserved, short
from schemas.plan import Action, AptStep, BuildStep, Change, Phase, PipStep, Step, StepKind


def changes(app: AppTarget | None, seen: DepsObserved | None) -> list[Change]:
    """One change per apt package, pip requirement and ROS repository of the app."""
    if app is None or seen is None:
        return []
    deps = app.deps
    found: list[Change] = []
    for name in deps.apt:
        missing = name in seen.apt_missing
        found.append(Change(
            address=f"apt.{name}", action=Action.CREATE if missing else Action.NOOP,
            reason="missing: installed with apt before the cutover" if missing
            else "installed"))
    for requirement in deps.pip:
        unsatisfied = requirement in seen.pip_unsatisfied
        if unsatisfied:
            reason = "not in the app's environment: installed with pip before the cutover"
        elif not seen.venv_ready:
            reason = "satisfied by the system's packages; the app's environment is created"
        else:
            reason = "in the app's environment"
        action = Action.CREATE if unsatisfied or not seen.venv_ready else Action.NOOP
        found.append(Change(address=f"pip.{requirement}", action=action, reason=reason))
    for source in deps.ros:
        commit = source.commit
        before = seen.ros_installed.get(source.name)
        if seen.ros_built:
            action, reason = Action.NOOP, f"at {short(commit)}, built"
        elif before is not None and before != commit:
            action = Action.UPDATE
            reason = f"{before[:8]} → {short(commit)[:8] if commit else UNKNOWN} (rebuild)"
        elif before is not None:
            action, reason = Action.UPDATE, f"at {short(commit)}, rebuilt with the workspace"
        else:
            action, reason = Action.CREATE, f"at {short(commit)} (build)"
        if action is not Action.NOOP:
            reason += " before the cutover, in its own build space"
        found.append(Change(address=f"ros.{source.name}", action=action, reason=reason))
    return found


def steps(app: AppTarget | None, seen: DepsObserved | None) -> list[Step]:
    """The preparation steps for what `changes` found missing."""
    if app is None or seen is None:
        return []
    deps = app.deps
    found: list[Step] = []
    if seen.apt_missing:
        found.append(AptStep(id=step_id(StepKind.APT, app.name), phase=Phase.PREPARE,
                             app=app.name, packages=list(seen.apt_missing)))
    if deps.pip and (seen.pip_unsatisfied or not seen.venv_ready):
        found.append(PipStep(id=step_id(StepKind.PIP, app.name), phase=Phase.PREPARE,
                             app=app.name, requirements=list(deps.pip)))
    if deps.ros and not seen.ros_built and deps.workspace is not None:
        found.append(BuildStep(
            id=step_id(StepKind.BUILD, deps.ros_build or UNKNOWN), phase=Phase.PREPARE,
            app=app.name, build=deps.ros_build or UNKNOWN, workspace=deps.workspace.path,
            user=deps.workspace.user,
            ros={r.name: r.commit or UNKNOWN for r in deps.ros},
            ros_keys={r.name: r.key for r in deps.ros},
            ros_urls={r.name: r.url for r in deps.ros}))
    return found
