"""Run an app's lifecycle scripts (install.sh, uninstall.sh, start.sh, stop.sh).

Scripts run as `bash SCRIPT` from an argument list, never a shell string built from
names (the old tool's Bluetooth service was exploitable that way); cwd is the app's
generation folder; the environment is small and explicit: LPAM_ROOT, LPAM_APP,
LPAM_APP_DIR and the app's parameters. Each script has a timeout, after which its whole
process group is killed; all output goes to the apply's log file.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
from dataclasses import dataclass
from pathlib import Path

from reconciler.errors import StepError

PASSED_THROUGH = ("PATH", "HOME", "LANG", "LC_ALL", "TERM", "USER", "LOGNAME", "TZ")
DEFAULT_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"


@dataclass(frozen=True)
class ScriptRunner:
    """Runs scripts of one apply; `log` collects every script's output."""

    root: Path
    log: Path
    timeout: float = 600.0

    def run(self, app: str, app_dir: Path, script: str, params: dict[str, str]) -> bool:
        """Run `script` if the app has it; False when it does not. StepError on failure."""
        path = app_dir / script
        if not path.is_file():
            self._note(f"== {app}: no {script}, nothing to run\n")
            return False
        env = {k: os.environ[k] for k in PASSED_THROUGH if k in os.environ}
        env.setdefault("PATH", DEFAULT_PATH)
        env.update(params)
        env.update(LPAM_ROOT=str(self.root), LPAM_APP=app, LPAM_APP_DIR=str(app_dir))
        self.log.parent.mkdir(parents=True, exist_ok=True)
        self._note(f"== {app}: bash {script} (in {app_dir})\n")
        with self.log.open("ab") as out:
            try:
                proc = subprocess.Popen(
                    ["bash", script], cwd=app_dir, env=env, stdin=subprocess.DEVNULL,
                    stdout=out, stderr=subprocess.STDOUT, process_group=0,
                )
            except OSError as exc:
                raise StepError(f"{app}: cannot run {script}: {exc.strerror}") from None
            try:
                code = proc.wait(timeout=self.timeout)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                raise StepError(
                    f"{app}: {script} did not finish within {self.timeout:g} s and was killed",
                    hint=f"see {self.log}; raise --script-timeout if it needs longer",
                ) from None
        if code != 0:
            raise StepError(
                f"{app}: {script} failed with exit code {code}",
                hint=f"see its output in {self.log}; fix the script and apply again",
            )
        return True

    def _note(self, text: str) -> None:
        self.log.parent.mkdir(parents=True, exist_ok=True)
        with self.log.open("a", encoding="utf-8") as out:
            out.write(text)
