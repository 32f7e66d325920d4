"""Run an app's lifecycle scripts (install.sh, uninstall.sh, start.sh, stop.sh).

Scripts run as `bash SCRIPT` from an argument list, never a shell string built from
names (the old tool's Bluetooth service was exploitable that way); cwd is the app's
generation folder; the environment is small and explicit: LPAM_ROOT, LPAM_APP,
LPAM_APP_DIR and the app's parameters (names that change how bash or the loader behave
are refused when the desired state is validated).

A script must never outlive what lpam knows about it. Each runs under a tiny bash
*guard* (`GUARD`), in its own process group — made by `start_new_session` (setsid, done in
C between fork and exec, so safe beside the executor's threads, unlike `preexec_fn`; Python
3.9 has no `process_group=`). The group is the same; the script also has no controlling
terminal, so a script that asks the terminal (sudo, debconf) fails instead of hanging:
- the guard holds the apply lock's descriptor (scripts themselves do not: a daemon that
  `start.sh` leaves behind must not hold the lock forever), so if lpam is killed, no later
  apply starts until the script has ended;
- the guard writes the script's exit code to `var/lib/lpam/runs/<run>.exit` when it ends,
  even if lpam died meanwhile, so the next apply knows whether to run it again;
- on Ctrl-C or SIGTERM lpam stops the whole group (TERM, then KILL) before it exits; a
  script over its timeout is killed the same way.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from reconciler.base.errors import DETAIL_LINES, StepError
from reconciler.base.reading import open_append, tail
from reconciler.engine.execution.ports import DEFAULT_PATH

PASSED_THROUGH = ("PATH", "HOME", "LANG", "LC_ALL", "TERM", "USER", "LOGNAME", "TZ")
GRACE_SECONDS = 5.0

# $1: exit-code file, $2: lock descriptor to keep from the script ("" for none), rest: command.
GUARD = r"""
res=$1; fd=$2; shift 2
if [ -n "$fd" ]; then "$@" {fd}>&-; else "$@"; fi
code=$?
printf '%s\n' "$code" > "$res.tmp" && mv -f "$res.tmp" "$res"
exit "$code"
"""


@dataclass(frozen=True)
class ScriptRunner:
    """Runs scripts of one apply; `log` collects every script's output."""

    root: Path
    log: Path
    runs: Path
    timeout: float = 600.0
    lock_fd: int | None = None
    note: Callable[[str], None] | None = None  # tells the lock file what is running

    def run(
        self, app: str, app_dir: Path, script: str, params: dict[str, str], *,
        run: str, required: bool = False,
    ) -> bool:
        """Run `script` if the app has it; False when it has not (StepError when it must).
        StepError on failure. `run` names the exit-code file the guard writes."""
        path = app_dir / script
        if not path.is_file():
            if required:
                raise StepError(
                    f"{app}: {script} is missing from {app_dir}, though the app had it when "
                    "it was staged",
                    hint="something (often the app's own install.sh) deleted it; fix the "
                    "app so it leaves its folder alone, then apply again",
                )
            self._note(f"== {app}: no {script}, nothing to run\n")
            return False
        env = self._env(app, app_dir, params)
        self.runs.mkdir(parents=True, exist_ok=True)
        result = self.runs / f"{run}.exit"
        fd = "" if self.lock_fd is None else str(self.lock_fd)
        self._note(f"== {app}: bash {script} (in {app_dir})\n")
        begun = self._size()  # its output starts here: what a failure shows of it
        try:
            proc = self._spawn(
                ["bash", "-c", GUARD, "lpam-guard", str(result), fd, "bash", script], app_dir,
                env, pass_fds=() if self.lock_fd is None else (self.lock_fd,))
        except OSError as exc:
            raise StepError(f"{app}: cannot run {script}: {exc.strerror}") from None
        if self.note is not None:
            self.note(f"running {app} {script} in process group {proc.pid}")
        try:
            code = proc.wait(timeout=self.timeout)
        except subprocess.TimeoutExpired:
            stop_group(proc)
            raise StepError(
                f"{app}: {script} did not finish within {self.timeout:g} s and was killed",
                hint=f"see {self.log}; raise --script-timeout if it needs longer",
                details=self._output(script, begun),
            ) from None
        except BaseException:  # Ctrl-C, SIGTERM: the script must not outlive lpam
            stop_group(proc)
            raise
        finally:
            if self.note is not None:
                self.note("applying")
        if code != 0:
            raise StepError(
                f"{app}: {script} failed with exit code {code}",
                hint=f"see its output in {self.log}; fix the script and apply again",
                details=self._output(script, begun),
            )
        return True

    def _spawn(self, argv: list[str], app_dir: Path, env: dict[str, str], *,
               pass_fds: tuple[int, ...] = ()) -> subprocess.Popen[bytes]:
        """`argv` in the app's folder, in its own process group, its output appended to
        the log."""
        out = open_append(self.log)
        try:
            return subprocess.Popen(
                argv, cwd=app_dir, env=env, stdin=subprocess.DEVNULL, stdout=out,
                stderr=subprocess.STDOUT, start_new_session=True, pass_fds=pass_fds)
        finally:
            os.close(out)

    def _env(self, app: str, app_dir: Path, params: dict[str, str]) -> dict[str, str]:
        env = passed_through()
        env.update(params)
        env.update(LPAM_ROOT=str(self.root), LPAM_APP=app, LPAM_APP_DIR=str(app_dir))
        # The folder is a link to the generation: `$PWD` names the link, as after `cd`
        # into it, so a script that builds paths from it finds /etc/libpanda.d/apps/…
        env["PWD"] = str(app_dir)
        return env

    def check(
        self, app: str, app_dir: Path, argv: list[str], params: dict[str, str], *,
        timeout: float,
    ) -> tuple[bool, str]:
        """Run a health check (an argument list, in the app's folder, with its parameters);
        its output goes to the apply log. A check over `timeout` is killed with its group."""
        self._note(f"== {app}: health check {argv!r} (in {app_dir})\n")
        try:
            proc = self._spawn(argv, app_dir, self._env(app, app_dir, params))
        except OSError as exc:
            return False, f"cannot run it: {exc.strerror}"
        try:
            code = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            stop_group(proc)
            return False, f"it did not finish within {timeout:g} s"
        except BaseException:
            stop_group(proc)
            raise
        return code == 0, f"exit code {code} (output in {self.log})"

    def _size(self) -> int:
        try:
            return self.log.stat().st_size
        except OSError:
            return 0

    def _output(self, script: str, begun: int) -> list[str]:
        """The script's last lines of output, for the error that explains its failure, as a
        failed health check shows its unit's (engine/execution/supervision.py log_tail)."""
        return [f"{script}: {line}" for line in tail(self.log, DETAIL_LINES, since=begun)]

    def _note(self, text: str) -> None:
        fd = open_append(self.log)
        try:
            os.write(fd, text.encode())
        finally:
            os.close(fd)


def passed_through() -> dict[str, str]:
    """The variables of lpam's environment a script or a supervisord gets, PATH at least."""
    env = {k: os.environ[k] for k in PASSED_THROUGH if k in os.environ}
    env.setdefault("PATH", DEFAULT_PATH)
    return env


def stop_group(proc: subprocess.Popen[bytes]) -> None:
    """TERM the script's process group, then KILL whatever is left after a grace period."""
    for sig, wait in ((signal.SIGTERM, GRACE_SECONDS), (signal.SIGKILL, None)):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        try:
            proc.wait(timeout=wait)
            break
        except subprocess.TimeoutExpired:
            continue
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)  # stragglers of a group whose leader ended
