"""The CLI's promises: bad input gets one clear line (file:line:column for documents), exit
1, no traceback, and the running app untouched; the other commands do what they say."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.gitserver import GitDaemon, RepoBuilder, closed_port
from tests.integration.apps import Lpam, apps_repo, desired

TOP = Path(__file__).resolve().parents[2]


def bad_inputs(url: str, closed: str) -> list[tuple[str, bytes, str]]:
    good = desired(url, "alpha")
    return [
        ("malformed", b"version: 1\napp: [alpha\n", ":3:1:"),
        ("tab", b"version: 1\napp:\n\tname: alpha\n", ":3:1: tab"),
        ("unknown key", good.replace("app:", "ap:").encode(), ":4:1: unknown key 'ap'"),
        ("wrong type", b"version: 1\nrepositories: 7\n", ":2:1:"),
        ("duplicate key", (good + "app: beta\n").encode(), "duplicate key"),
        ("empty", b"", "file is empty"),
        ("binary", b"\x7fELF\x02\x01\x00\x00", "binary"),
        ("newer version", good.replace("version: 1", "version: 9").encode(), "version 9"),
        ("slash in app", good.replace("name: alpha", "name: a/b").encode(), ":5:3:"),
        ("dotdot app", good.replace("name: alpha", "name: ..").encode(), ":5:3:"),
        ("shell url", desired(f"'{url};reboot'", "alpha").encode(), ":3:5:"),
        ("dash url", desired("-oProxyCommand=x", "alpha").encode(), ":3:5:"),
        ("shell ref", desired(url, "alpha", ref="'$(reboot)'").encode(), ":4:5:"),
        ("dash ref", desired(url, "alpha", ref="--force").encode(), ":4:5:"),
        ("unreachable", desired(closed, "alpha").encode(), "the server refused the connection"),
        ("missing ref", desired(url, "alpha", ref="nope").encode(), "not found"),
        ("unknown app", desired(url, "gamma").encode(), "not in the catalog"),
    ]


def test_bad_input_gets_a_clear_error_and_changes_nothing(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    url = git_daemon.url("apps.git")
    lpam = Lpam(tmp_path / "root")
    path = lpam.desired(desired(url, "alpha"))
    assert lpam("apply", "--yes").returncode == 0
    before, events = lpam.status(), lpam.events()
    with closed_port() as port:
        closed = f"git://127.0.0.1:{port}/apps.git"
        for name, content, expected in bad_inputs(url, closed):
            path.write_bytes(content)
            for command in (["plan"], ["apply", "--yes"]):
                done = lpam(*command)
                assert done.returncode == 1, (name, command, done.stdout, done.stderr)
                assert expected in done.stderr, (name, done.stderr)
                assert "Traceback" not in done.stderr + done.stdout, name
                assert done.stderr.startswith("error: "), name
                assert len(done.stderr.strip().splitlines()) <= 2, (name, done.stderr)
            assert lpam.status() == before, name
            assert lpam.events() == events, name


def test_unreachable_server_gives_up_in_bounded_time(tmp_path: Path) -> None:
    with socket.socket() as listener:  # accepts, never answers: a stuck server
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        lpam = Lpam(tmp_path / "root")
        url = f"git://127.0.0.1:{listener.getsockname()[1]}/x.git"
        lpam.desired(desired(url, "alpha"))
        started = time.monotonic()
        done = lpam("plan", "--network-timeout", "1", timeout=120)
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert "no answer within 1 s" in done.stderr
    assert time.monotonic() - started < 120


def test_version_status_and_validate(tmp_path: Path) -> None:
    lpam = Lpam(tmp_path / "root")
    version = lpam("--version")
    assert version.returncode == 0 and version.stdout.startswith("lpam ")
    empty = lpam("status")
    assert empty.returncode == 0 and "No app repositories" in empty.stdout
    assert lpam.status()["app"] is None
    ok = lpam("validate", str(TOP / "desired-state.example.yaml"))
    assert ok.returncode == 0 and "desired state" in ok.stdout
    catalog = lpam("validate", str(TOP / "examples/example-apps/libpanda-apps.yaml"))
    assert catalog.returncode == 0
    assert "3 apps (can-logger, speed-monitor, speed-logger)" in catalog.stdout
    folder = lpam("validate", str(TOP / "examples/example-apps"))
    assert folder.returncode == 0 and "app repository" in folder.stdout
    broken = tmp_path / "apps"
    broken.mkdir()
    (broken / "libpanda-apps.yaml").write_text("apps:\n  - name: ghost\n")
    missing = lpam("validate", str(broken))
    assert missing.returncode == 1 and "folder 'ghost' does not exist" in missing.stderr
    assert not (tmp_path / "root").exists()  # validate and status write nothing


def test_validate_says_which_kind_it_read_and_takes_kind(tmp_path: Path) -> None:
    lpam = Lpam(tmp_path / "root")
    agent = tmp_path / "agent.yaml"
    agent.write_text("version: 1\nsource: {url: 'https://h/fleet'}\nvehicle: rav4-07\n")
    done = lpam("validate", str(agent))
    assert done.returncode == 0 and "is agent settings" in done.stdout, done.stderr
    forced = lpam("validate", "--kind", "desired-state", str(agent))
    assert forced.returncode == 1
    assert forced.stderr.startswith(f"error: {agent}:3:1: vehicle: Input should be a valid "
                                    "dictionary")  # the report, now only when forced
    vague = tmp_path / "vague.yaml"
    vague.write_text("version: 1\n")
    unknown = lpam("validate", str(vague))
    assert unknown.returncode == 1 and "Traceback" not in unknown.stderr
    assert unknown.stderr.startswith(f"error: {vague}:1:1: cannot tell which kind")
    assert "--kind desired-state" in unknown.stderr
    assert lpam("validate", "--kind", "desired-state", str(vague)).returncode == 0
    assert not (tmp_path / "root").exists()


def test_apply_without_yes_refuses_when_not_interactive(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon
) -> None:
    apps_repo(make_repo("apps.git"))
    lpam = Lpam(tmp_path / "root")
    lpam.desired(desired(git_daemon.url("apps.git"), "alpha"))
    done = subprocess.run(
        [sys.executable, "-m", "reconciler", "--root", str(lpam.root), "apply"],
        capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=60,
    )
    assert done.returncode == 1 and "--yes" in done.stderr
    assert lpam.status()["app"] is None


@pytest.mark.parametrize("era", ["csv", "yaml-0.0"])
def test_import_lpam_writes_a_desired_state_lpam_accepts(tmp_path: Path, era: str) -> None:
    etc = tmp_path / "libpanda.d"
    etc.mkdir()
    if era == "csv":
        (etc / "app-manifest.csv").write_text("jmscslgroup/libpanda-default-apps, main\n\n")
        (etc / "app").write_text("pandarecord\n")
    else:
        (etc / "app-manifest.yaml").write_text(
            "version: 0.0\nrepositories:\n  jmscslgroup/libpanda-default-apps:\n"
            "    branch: main\ncurrent: pandarecord\n")
    out = tmp_path / "desired.yaml"
    lpam = Lpam(tmp_path / "root")
    done = lpam("import-lpam", str(etc), "-o", str(out))
    assert done.returncode == 0, done.stderr
    checked = lpam("validate", str(out))
    assert checked.returncode == 0, checked.stderr
    assert "1 repository, app pandarecord" in checked.stdout  # not "1 repositories"
    again = lpam("import-lpam", str(etc), "-o", str(out))
    assert again.returncode == 1 and "will not overwrite" in again.stderr
    missing = lpam("import-lpam", str(tmp_path / "nowhere"))
    assert missing.returncode == 1 and "Traceback" not in missing.stderr
