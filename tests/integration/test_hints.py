"""Every command lpam suggests runs as printed, from any directory (issue 30, item 13).

A user copies a hint into whatever shell they are in. A hint that repeats a relative path
as typed, or drops `--root`, acts on another file or on the car's / instead of the
sandbox. Each test here gives lpam relative paths from one directory, takes the command
it printed, and runs it verbatim from another.
"""

from __future__ import annotations

import json
import os
import pty
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo, desired
from tests.integration.test_takeover import lpam_vehicle

TOP = Path(__file__).resolve().parents[2]


def lpam_in(cwd: Path, *args: str, answer: str | None = None,
            ) -> subprocess.CompletedProcess[str]:
    """The real `lpam ARGS` run in `cwd` (this tree's lpam, whatever the directory);
    `answer`: typed at a terminal when lpam asks (an apply without --yes)."""
    env = {**os.environ, "PYTHONPATH": str(TOP)}
    env.pop("LPAM_ROOT", None)
    if answer is None:
        return subprocess.run([sys.executable, "-m", "reconciler", *args], cwd=cwd, env=env,
                              capture_output=True, text=True, timeout=120, check=False,
                              stdin=subprocess.DEVNULL)
    typing, terminal = pty.openpty()
    try:
        os.write(typing, f"{answer}\n".encode())
        return subprocess.run([sys.executable, "-m", "reconciler", *args], cwd=cwd, env=env,
                              capture_output=True, text=True, timeout=120, check=False,
                              stdin=terminal)
    finally:
        os.close(typing)
        os.close(terminal)


def suggested(text: str) -> list[str]:
    """The commands `text` suggests: each `lpam …` in backquotes."""
    return re.findall(r"`(lpam [^`]*)`", text)


def verbatim(command: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """`command` as printed, typed into a shell at a terminal in `cwd`, and `yes` when it
    asks (a resumed apply shows its plan and asks again)."""
    words = shlex.split(command)
    assert words[0] == "lpam", command
    return lpam_in(cwd, *words[1:], answer="yes")


@pytest.fixture
def places() -> Iterator[tuple[Path, Path]]:
    """`here` (where the user types, the sandbox's root under it) and `elsewhere`, in a
    short folder: pytest's own paths are too long for supervisord's socket under
    `here/root` (a unix socket's path has at most 99 bytes). Any service manager started
    there is shut down at the end."""
    base = Path(tempfile.mkdtemp(prefix="lpam-hints-"))
    here, elsewhere = base / "here", base / "elsewhere"
    here.mkdir()
    elsewhere.mkdir()
    try:
        yield here, elsewhere
    finally:
        if (here / "root").exists():
            lpam_in(here, "--root", "root", "services", "shutdown")
        shutil.rmtree(base, ignore_errors=True)


HELD = ('touch "$LPAM_ROOT/installing"\n'
        'if [ -e "$LPAM_ROOT/hold" ]; then for _ in $(seq 600); do sleep 0.05; done; fi')
"""alpha's install.sh: while `hold` exists, it runs on (30 s at most) for the test to
interrupt lpam under it."""


def interrupted(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """`lpam ARGS` in `cwd`, given Ctrl-C once alpha's install.sh runs."""
    env = {**os.environ, "PYTHONPATH": str(TOP)}
    env.pop("LPAM_ROOT", None)
    running = subprocess.Popen([sys.executable, "-m", "reconciler", *args], cwd=cwd, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not (cwd / "root/installing").exists() and running.poll() is None:
            assert time.monotonic() < deadline, "install.sh never ran"
            time.sleep(0.05)
        running.send_signal(signal.SIGINT)
        out, err = running.communicate(timeout=60)
    finally:
        if running.poll() is None:
            running.kill()
            running.wait()
    return subprocess.CompletedProcess(running.args, running.returncode, out, err)


def test_a_resume_hint_and_a_stops_hint_run_as_printed_from_elsewhere(
    places: tuple[Path, Path], make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"), alpha={"install": HELD})
    here, elsewhere = places
    (here / "my state.yaml").write_text(desired(git_daemon.url("apps.git"), "alpha"))
    (here / "root").mkdir()
    (here / "root/hold").touch()
    root = ["--root", "root", "--services", "supervisor"]
    try:
        cut = interrupted(here, *root, "--script-timeout", "100", "apply", "-f",
                          "my state.yaml", "--yes")
        assert cut.returncode == 130, cut.stderr
        [resume] = suggested(cut.stderr)
        table = lpam_in(elsewhere, "--root", str(here / "root"), "status").stdout
        [last] = [line for line in table.splitlines() if line.startswith("Last apply:")]
        assert last.count("interrupted") == 1, last  # not "interrupted at …: interrupted"
        assert f"`{resume}` goes on from where it stood" in last, last
        assert shlex.split(resume) == [
            "lpam", "--root", str(here / "root"), "--services", "supervisor",
            "--script-timeout", "100", "apply", "-f", str(here / "my state.yaml")], resume
        (here / "root/hold").unlink()
        resumed = verbatim(resume, elsewhere)
        assert resumed.returncode == 0, resumed.stderr
        assert "Apply complete" in resumed.stdout

        (here / "my state.yaml").write_text(
            desired(git_daemon.url("apps.git"), "alpha", MODE="two"))
        changed = lpam_in(here, *root, "apply", "-f", "my state.yaml", "--yes")
        assert changed.returncode == 0, changed.stderr
        stopped = lpam_in(here, *root, "stop")
        assert stopped.returncode == 0, stopped.stderr
        # the hold names the file it holds against as a path that means it anywhere
        shown = lpam_in(elsewhere, "--root", str(here / "root"), "status", "--json")
        [hold] = json.loads(shown.stdout)["holds"]
        assert f"({here / 'my state.yaml'})" in hold["ends"], hold
        [start] = suggested(stopped.stdout)
        assert start.startswith(f"lpam --root {here / 'root'} "), start
        started = verbatim(start, elsewhere)
        assert started.returncode == 0 and "Started alpha" in started.stdout, started.stderr

        (here / "my state.yaml").write_text(
            desired(git_daemon.url("apps.git"), "alpha", MODE="three"))
        planned = lpam_in(here, *root, "plan", "-f", "my state.yaml", "-o", "the plan.json")
        assert planned.returncode == 0, planned.stderr
        [apply] = suggested(planned.stdout.split("Saved the plan")[1])
        applied = verbatim(apply, elsewhere)
        assert applied.returncode == 0 and "Apply complete" in applied.stdout, applied.stderr

        # the hold's own way out applies the file it holds against, not the default one
        assert lpam_in(here, *root, "stop").returncode == 0
        table = lpam_in(here, *root, "status").stdout
        release = next(c for c in suggested(table) if c.endswith(" --release"))
        assert str(here / "my state.yaml") in shlex.split(release), release
        released = verbatim(release, elsewhere)
        assert released.returncode == 0, released.stderr
        shown = lpam_in(elsewhere, "--root", str(here / "root"), "status", "--json")
        assert json.loads(shown.stdout)["holds"] == [], shown.stdout
    finally:
        lpam_in(here, *root, "services", "shutdown")


def test_import_lpams_hint_keeps_the_root(
    places: tuple[Path, Path], make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    repo = make_repo("apps.git")
    commit = apps_repo(repo)
    here, elsewhere = places
    lpam_vehicle(Lpam(here / "root"), repo, commit)
    done = lpam_in(here, "--root", "root", "import-lpam", "-o", "imported.yaml")
    assert done.returncode == 0, done.stderr
    [plan] = suggested(done.stdout)
    # the test's repository is served by the loopback daemon, not GitHub
    written = here / "imported.yaml"
    written.write_text(written.read_text().replace("repo: lab/apps",
                                                   f"url: {git_daemon.url('apps.git')}"))
    planned = verbatim(plan, elsewhere)
    assert planned.returncode == 0, planned.stderr
    assert "adopted in place" in planned.stdout, planned.stdout  # it read LPAM's root
