"""`libpanda-app-manager` end to end: the real console script, a real --root (LPAM_ROOT),
GitHub repositories served by a real `git daemon` (the desired state's `mirrors:` sends
https://github.com/ to it), and apps under a real supervisord.

What a user (or bluezone) checks: `-d` prints LPAM's table and bluezone's own parsing
reads it; `-i` switches apps and the new one really runs; every refusal exits non-zero
with one line on stderr, leaves the desired state byte-identical and the app running; an
added and removed repository leaves the file's comments; `-u`, `-s`, `-k`, `-c`, `-l`,
`-t` and `-p` do what LPAM's did, with exit codes that tell the truth.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.errors import LpamError
from reconciler.base.layout import Layout
from reconciler.workflow.applying import ApplyOptions
from reconciler.workflow.machine import Machine
from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import TICKER, FieldCar, Lpam, applied, field_repos

CATALOG = """\
apps:
  - name: ticker
    command: [python3, -u, run.py]
    health: {settle_seconds: 0.5}
  - name: tocker
    command: [python3, -u, run.py]
    health: {settle_seconds: 0.5}
  - name: crasher
    command: [python3, -u, run.py]
    health: {settle_seconds: 1}
"""
TOCKER = 'Données GPS → CAN, "quoted" \\ back'
HEADER = "Repository\tBranch\tApp\tService\tEnabled\tRunning\tDescription"


class Shim(FieldCar):
    """The real `libpanda-app-manager`, in a subprocess, on LPAM_ROOT=root."""

    def __call__(self, *args: str, timeout: float = 120,
                 env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        env = {**(os.environ if env is None else env), "LPAM_ROOT": str(self.root)}
        return subprocess.run([sys.executable, "-m", "reconciler.frontends.shim", *args],
                              capture_output=True, text=True, timeout=timeout, env=env)

    def ok(self, *args: str) -> str:
        done = self(*args)
        assert done.returncode == 0, (args, done.stdout, done.stderr)
        said = [line for line in done.stderr.splitlines()  # what a fetch cost is told
                if not re.fullmatch(r"note: fetched .*\((the commit alone|with its history|"
                                    r"each commit alone|some with their history)\)", line)]
        assert said == [], done.stderr
        return done.stdout

    def refused(self, *args: str, code: int = 1) -> str:
        """The command fails with `code` and one line on stderr, changing nothing."""
        before = self.desired.read_bytes()
        done = self(*args)
        assert done.returncode == code, (args, done.stdout, done.stderr)
        lines = done.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("libpanda-app-manager: error: "), \
            done.stderr
        assert "Traceback" not in done.stdout + done.stderr
        assert self.desired.read_bytes() == before, args
        return lines[0]

    def unit(self) -> dict[str, object]:
        found: dict[str, object] = self.app()["unit"]
        return found


@pytest.fixture
def shim(tmp_path: Path, git_daemon: GitDaemon, make_repo: Callable[[str], RepoBuilder]
         ) -> Iterator[Shim]:
    files = {"crasher/run.py": "import sys\nsys.exit(3)\n"}
    for name, text in (("ticker", "ticks"), ("tocker", TOCKER)):
        files[f"{name}/run.py"] = TICKER
        files[f"{name}/description.txt"] = text + "\nsecond line\n"
    field_repos(make_repo, CATALOG, files)
    runner = Shim(tmp_path / "root")
    with applied(runner, git_daemon.port):
        yield runner


def bluezone_rows(output: bytes) -> list[dict[str, str]]:
    """What bluezone's `app_info` (libpanda scripts/bluezone/bluezone.py) makes of `-d`'s
    output, re-implemented from reading it: its decoding chain, the lines after the
    header up to the trailing newline, tab-split, quotes removed from the description."""
    text = output.decode("utf-8").encode("latin1").decode("unicode_escape") \
        .encode("latin1").decode("utf8")
    rows = []
    for line in text.split("\n")[1:-1]:
        columns = line.split("\t")
        rows.append({"repository": columns[0], "branch": columns[1], "app": columns[2],
                     "service": columns[3], "enabled": columns[4], "running": columns[5],
                     "description": columns[6].replace('"', "")})
    return rows


def running_pid(shim: Shim) -> int:
    unit = shim.unit()
    assert unit["active"] == "active", unit
    pid = unit["pid"]
    assert isinstance(pid, int)
    os.kill(pid, 0)  # alive
    return pid


def gone(pid: int) -> bool:
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.1)
    return False


def test_the_table_is_lpams_and_bluezone_reads_it(shim: Shim) -> None:
    out = shim.ok("-d")
    lines = out.split("\n")
    assert lines[0] == HEADER and lines[-1] == ""
    assert lines[1] == "fleet/apps\tmain\tticker\tlpam-app-ticker\tyes\tyes\t\"ticks\""
    assert lines[2].startswith("fleet/apps\tmain\ttocker\tlpam-app-tocker\tno\tno\t\"")
    assert out.isascii()
    rows = bluezone_rows(subprocess.run(
        [sys.executable, "-m", "reconciler.frontends.shim", "-d"], capture_output=True, check=True,
        env={**os.environ, "LPAM_ROOT": str(shim.root)}).stdout)
    assert rows == [
        {"repository": "fleet/apps", "branch": "main", "app": "ticker",
         "service": "lpam-app-ticker", "enabled": "yes", "running": "yes", "description": "ticks"},
        # not installed: the unit lpam will run it as, never an empty Service
        {"repository": "fleet/apps", "branch": "main", "app": "tocker",
         "service": "lpam-app-tocker", "enabled": "no", "running": "no",
         "description": TOCKER.replace('"', "")},
        {"repository": "fleet/apps", "branch": "main", "app": "crasher",
         "service": "lpam-app-crasher", "enabled": "no", "running": "no", "description": ""},
    ]
    assert shim.ok("-l") == "ticker tocker crasher\n"
    assert shim.ok("-c") == "ticker\n"
    assert shim.ok("-t") == "ticker: unit lpam-app-ticker active (running)\n"
    # clustered as getopts reads them, in the order given
    assert shim.ok("-cl") == "ticker\nticker tocker crasher\n"


def test_i_switches_the_app_and_it_really_runs(shim: Shim) -> None:
    old = running_pid(shim)
    before = shim.desired.read_text()
    out = shim.ok("-itocker")
    assert "App tocker enabled" in out
    assert gone(old)
    assert shim.unit()["name"] == "lpam-app-tocker"
    running_pid(shim)
    assert shim.ok("-c") == "tocker\n"
    text = shim.desired.read_text()
    assert "name: tocker" in text and "name: ticker" not in text
    assert text.replace("tocker", "ticker") == before  # comments and layout kept
    rows = bluezone_rows(shim.ok("-d").encode())
    assert [(r["app"], r["enabled"], r["running"]) for r in rows] == \
        [("ticker", "no", "no"), ("tocker", "yes", "yes"), ("crasher", "no", "no")]
    # the same app again: nothing to do, success
    assert shim("-i", "tocker").returncode == 0 and shim.desired.read_text() == text


def login_name() -> str:
    """The user's name as they know it: their login, else their account."""
    import pwd

    try:
        return os.getlogin()
    except OSError:  # no terminal here (a CI runner)
        return pwd.getpwuid(os.getuid()).pw_name


def test_history_names_the_user_who_made_each_change(shim: Shim) -> None:
    """The shim and the CLI record who ran them (issue 31): `SUDO_USER` under sudo (a
    car's lpam runs as root), else the login name — in `lpam history` (its By column and
    `--json`) and in status's last apply."""
    unsudo = {k: v for k, v in os.environ.items() if k != "SUDO_USER"}
    assert shim("-itocker", env={**unsudo, "SUDO_USER": "alice"}).returncode == 0
    assert shim("-iticker", env=unsudo).returncode == 0
    shim.desired.write_text(shim.desired.read_text().replace("ticker", "tocker"))
    done = subprocess.run([sys.executable, "-m", "reconciler", "--root", str(shim.root),
                           "apply", "--yes"], capture_output=True, text=True, timeout=120,
                          env={**unsudo, "SUDO_USER": "carol"})
    assert done.returncode == 0, done.stderr
    entries = json.loads(shim.lpam("history", "--json").stdout)
    first = os.environ.get("SUDO_USER") or login_name()  # the fixture's `lpam apply`
    assert [(e["app"], e["by"]) for e in entries] == [
        ("ticker", {"kind": "user", "id": first, "via": "lpam"}),
        ("tocker", {"kind": "user", "id": "alice", "via": "libpanda-app-manager"}),
        ("ticker", {"kind": "user", "id": login_name(), "via": "libpanda-app-manager"}),
        ("tocker", {"kind": "user", "id": "carol", "via": "lpam"}),
    ]
    header, *rows = shim.lpam("history").stdout.splitlines()
    at = header.index("By")
    assert [row[at:].split("  ")[0] for row in rows] == [
        f"{first} (lpam)", "alice (libpanda-app-manager)",
        f"{login_name()} (libpanda-app-manager)", "carol (lpam)"]
    assert shim.lpam.status()["last_apply"]["by"] == \
        {"kind": "user", "id": "carol", "via": "lpam"}
    assert "(asked by carol (lpam))" in shim.lpam("status").stdout


def test_status_names_who_stopped_an_app(shim: Shim) -> None:
    """A stop holds its app until someone starts it: status's Held line and `--json` name
    who asked (issue 31) — the shim's user under sudo, the CLI's user — and a start ends
    the hold with its name."""
    unsudo = {k: v for k, v in os.environ.items() if k != "SUDO_USER"}
    assert shim("-k", env={**unsudo, "SUDO_USER": "alice"}).returncode == 0
    [hold] = shim.lpam.status()["holds"]
    assert "ticker was stopped by `lpam stop` (asked by alice (libpanda-app-manager)) " \
        "and stays stopped" in hold["what"], hold
    assert "(asked by alice (libpanda-app-manager))" in shim.lpam("status").stdout
    done = subprocess.run([sys.executable, "-m", "reconciler", "--root", str(shim.root),
                           "start"], capture_output=True, text=True, timeout=120,
                          env=unsudo)
    assert done.returncode == 0, done.stderr
    assert shim.lpam.status()["holds"] == []
    done = subprocess.run([sys.executable, "-m", "reconciler", "--root", str(shim.root),
                           "stop"], capture_output=True, text=True, timeout=120,
                          env={**unsudo, "SUDO_USER": "carol"})
    assert done.returncode == 0, done.stderr
    assert "(asked by carol (lpam))" in shim.lpam.status()["holds"][0]["what"]


def test_refusals_change_nothing_and_exit_non_zero(shim: Shim) -> None:
    pid = running_pid(shim)
    assert "not in the catalog" in shim.refused("-i", "gamma")
    assert "not found" in shim.refused("-g", "extra/tools", "-b", "nope")
    assert "no such repository" in shim.refused("-g", "extra/missing")
    assert "installed app ticker comes from fleet/apps" in shim.refused("-r", "fleet/apps")
    assert "not in the desired state" in shim.refused("-r", "extra/tools")
    assert "whitespace" in shim.refused("-i", "a b")
    assert "'..'" in shim.refused("-g", "x/..")
    assert "GitHub repository" in shim.refused("-g", "https://evil/x")
    # the cutover fails (health check, rolled back): the file says what runs, exit 3
    assert "crasher" in shim.refused("-i", "crasher", code=3)
    # usage errors: exit 2
    assert "refused" in shim.refused("-i", "--upload-pack=x", code=2)
    assert "refused" in shim.refused("-i--upload-pack=x", code=2)
    assert "-b BRANCH goes with -g" in shim.refused("-b", "main", code=2)
    assert "unknown option -x" in shim.refused("-x", code=2)
    assert "needs a value" in shim.refused("-i", code=2)
    bare = shim()  # LPAM's menu is gone: the usage says what to type instead
    assert (bare.returncode, bare.stdout) == (2, ""), bare
    assert bare.stderr.startswith("usage: libpanda-app-manager [-d]") and "  -i APP " in \
        bare.stderr and bare.stderr.splitlines()[-1].startswith(
            "libpanda-app-manager: error: no flag given"), bare.stderr
    assert "unexpected argument" in shim.refused("-c", "extra", code=2)
    # an earlier flag's failure stops the later ones
    assert "not in the catalog" in shim.refused("-i", "gamma", "-u")
    assert shim.ok("-c") == "ticker\n"
    assert shim.unit()["name"] == "lpam-app-ticker"
    running_pid(shim)
    assert pid


def test_a_repository_added_and_removed_keeps_the_files_comments(shim: Shim) -> None:
    before = shim.desired.read_text()
    out = shim.ok("-g", "extra/tools", "-b", "dev")
    assert "Repository extra/tools added" in out
    text = shim.desired.read_text()
    assert "\n- repo: extra/tools\n  ref: dev\napp:\n" in text
    assert text.startswith("# The car's apps") and "# the default apps" in text
    assert "# follow the branch" in text and "# end of file" in text
    assert "version: 1\n" in text
    rows = bluezone_rows(shim.ok("-d").encode())
    assert ("extra/tools", "dev", "gadget") in [(r["repository"], r["branch"], r["app"])
                                                for r in rows]
    # the same again: nothing changes, success; the app ran throughout
    assert shim("-g", "extra/tools", "-b", "dev").returncode == 0
    assert shim.desired.read_text() == text
    shim.ok("-r", "extra/tools")
    assert shim.desired.read_text() == before
    assert [r["app"] for r in bluezone_rows(shim.ok("-d").encode())] == \
        ["ticker", "tocker", "crasher"]
    running_pid(shim)


def test_u_s_k_and_t(shim: Shim) -> None:
    pid = running_pid(shim)
    assert "stays stopped" in shim.ok("-k")
    assert gone(pid) and shim.unit()["active"] == "inactive"
    assert shim.ok("-t") == "ticker: unit lpam-app-ticker inactive (stopped)\n"
    shim.ok("-s")
    running_pid(shim)
    assert shim.ok("-u").splitlines()[-1] == "No app enabled; no app is installed."
    assert shim.ok("-c") == "None\n"
    assert shim.ok("-t") == "inactive (none installed)\n"
    assert "\napp: null\n" in shim.desired.read_text()  # written as the README writes it
    assert "no app is installed" in shim.refused("-s")


def test_p_moves_branches_to_their_tips(shim: Shim, make_repo: Callable[[str], RepoBuilder],
                                        git_daemon: GitDaemon) -> None:
    apps = RepoBuilder(git_daemon.base, "fleet/apps", work_root=shim.root.parent / "w2",
                       home=Path(os.environ["HOME"]))
    apps.git("fetch", "--quiet", "origin")
    apps.git("reset", "--quiet", "--hard", "origin/main")
    apps.commit("new words", {"ticker/description.txt": "ticks faster\n"})
    apps.git("push", "--quiet", "origin", "HEAD:main")
    assert bluezone_rows(shim.ok("-d").encode())[0]["description"] == "ticks"  # offline
    out = shim.ok("-p")
    assert "Updated" in out
    assert bluezone_rows(shim.ok("-d").encode())[0]["description"] == "ticks faster"
    record = json.loads((shim.root / "var/lib/lpam/state.json").read_text())
    assert record["repositories"][0]["commit"] == apps.rev("HEAD")
    running_pid(shim)


def test_a_params_edit_restarts_the_app_without_reinstalling(shim: Shim) -> None:
    """The phone's `app_params`: the same function, in-process on the shim's root."""
    from reconciler.workflow.editing import set_params
    from reconciler.workflow.events import Event, Planned

    pid = running_pid(shim)
    kinds: list[str] = []

    def report(event: Event) -> None:
        if isinstance(event, Planned):
            kinds.extend(str(step.kind) for step in event.plan.steps)

    machine = Machine.at(Layout(shim.root))
    hand_edit = shim.desired.read_text() + "# a hand edit while the plan was made\n"

    def meddle(event: Event) -> None:
        if isinstance(event, Planned):
            shim.desired.write_text(hand_edit)

    with pytest.raises(LpamError, match="changed while this edit waited"):
        set_params(machine, "ticker", {"RATE": "5"}, by="phone",
                   options=ApplyOptions(lock_timeout=2), report=meddle)
    assert shim.desired.read_text() == hand_edit and running_pid(shim) == pid
    done = set_params(machine, "ticker", {"RATE": "20 Hz"}, by="phone",
                      options=ApplyOptions(lock_timeout=2), report=report)
    assert done.changed and kinds and not {"stage", "install", "uninstall"} & set(kinds)
    assert shim.desired.read_text().endswith(
        "app:\n  name: ticker\n  params:\n    RATE: 20 Hz\n# end of file\n"
        "# a hand edit while the plan was made\n")
    assert gone(pid)
    assert shim.lpam.status()["app"]["params"] == {"RATE": "20 Hz"}
    running_pid(shim)


def test_on_a_fleet_car_an_edit_is_a_local_override_that_p_ends(car: Lpam, fleet: RepoBuilder
                                                                 ) -> None:
    """The car follows a fleet repository (conftest: alpha for every car) and has no
    desired state of its own: `-i` starts one from the fleet's file, and the agent's next
    pass leaves it; `-p` ends it and the car follows its fleet again."""
    shim = Shim(car.root)
    try:
        assert car("sync").returncode == 0
        assert shim.ok("-c") == "alpha\n" and not shim.desired.exists()
        listed = bluezone_rows(shim.ok("-d").encode())
        assert [r["app"] for r in listed] == ["alpha", "beta"]
        # LPAM's Service: the app's `service` file, installed (alpha) or not (beta)
        assert [r["service"] for r in listed] == ["can", "can"]
        shim.ok("-i", "beta")
        assert shim.ok("-c") == "beta\n"
        first = shim.desired.read_text().splitlines()[0]
        assert first.startswith("#") and "Made on this car from the fleet's" in first
        override = json.loads(Layout(car.root).override.read_text())
        assert override["by"] == "libpanda-app-manager" and override["seeded"] is True
        assert car("sync").returncode == 0  # the agent's pass: the override holds
        assert shim.ok("-c") == "beta\n"
        assert "Ended the local override" in shim.ok("-p")
        assert shim.ok("-c") == "alpha\n"
        assert not Layout(car.root).override.exists() and not shim.desired.exists()
    finally:
        shutdown(Layout(car.root))
