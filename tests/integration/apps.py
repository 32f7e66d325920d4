"""Support for the CLI tests: an app repository whose scripts leave a trace, and a runner
for the real `lpam` command in a subprocess with its own --root; and the car that the
field frontends' tests (`libpanda-app-manager`, `lpam ble`) drive."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from reconciler.adapters.services.supervisor import shutdown
from reconciler.base.layout import Layout
from tests.gitserver import RepoBuilder

SCRIPT = """#!/usr/bin/env bash
set -euo pipefail
echo "$LPAM_APP:{script}:${{MODE:-}}" >> "$LPAM_ROOT/events.log"
{extra}
"""

CATALOG = """\
apps:
  - name: alpha
    path: alpha/
    properties:
      - owns_panda: true
  - name: beta
    properties:
      - owns_panda: true
"""


def add_app(repo: RepoBuilder, name: str, *, extra: dict[str, str] | None = None) -> None:
    """An app folder whose four scripts append `app:script:MODE` to $LPAM_ROOT/events.log."""
    for script in ("install", "uninstall", "start", "stop"):
        body = SCRIPT.format(script=script, extra=(extra or {}).get(script, ""))
        repo.write(f"{name}/{script}.sh", body, executable=True)
    repo.write(f"{name}/description.txt", f"the {name} app\n")
    repo.write(f"{name}/service", "can\n")


def apps_repo(
    repo: RepoBuilder, *, alpha: dict[str, str] | None = None, beta: dict[str, str] | None = None
) -> str:
    """Catalog with alpha and beta (with `extra` script lines); returns the pushed commit."""
    repo.write("libpanda-apps.yaml", CATALOG)
    add_app(repo, "alpha", extra=alpha)
    add_app(repo, "beta", extra=beta)
    first = repo.commit("alpha and beta")
    repo.push()
    return first


@dataclass
class Lpam:
    """The real CLI, in a subprocess, confined to `root`."""

    root: Path

    def __call__(self, *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "reconciler", "--root", str(self.root), *args],
            capture_output=True, text=True, timeout=timeout, env=dict(os.environ),
        )

    def spawn(self, *args: str) -> subprocess.Popen[str]:
        return subprocess.Popen(
            [sys.executable, "-m", "reconciler", "--root", str(self.root), *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        )

    def desired(self, text: str) -> Path:
        path = self.root / "etc" / "lpam" / "desired-state.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        return path

    def status(self) -> dict[str, Any]:
        done = self("status", "--json")
        assert done.returncode == 0, done.stderr
        result: dict[str, Any] = json.loads(done.stdout)
        return result

    def events(self) -> list[str]:
        log = self.root / "events.log"
        return log.read_text().split() if log.exists() else []


def processes(root: Path, script: bytes = b".py") -> list[int]:
    """The live app processes of this root (their environment names the root), whose
    command line holds `script`: one per copy of an app (a copy's own children, such as
    a python3 shim's helpers, are not copies)."""
    mark = f"LPAM_ROOT={root}".encode()
    found: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            env = (entry / "environ").read_bytes().split(b"\0")
            cmd = (entry / "cmdline").read_bytes()
            stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if mark in env and script in cmd and stat[0] not in ("Z", "X"):
            found[int(entry.name)] = int(stat[1])
    return sorted(pid for pid, parent in found.items() if parent not in found)


def desired(url: str, app: str | None, ref: str | None = None, **params: str) -> str:
    lines = ["version: 1", "repositories:", f"  - url: {url}"]
    if ref is not None:
        lines.append(f"    ref: {ref}")
    if app is None:
        lines.append("app: null")
    else:
        lines += ["app:", f"  name: {app}"]
        if params:
            lines.append("  params:")
            lines += [f'    {k}: "{v}"' for k, v in params.items()]
    return "\n".join(lines) + "\n"


# A car as the field frontends' tests use it (libpanda-app-manager, lpam ble): a desired
# state of its own whose GitHub repositories come from the test's git daemon, and an app
# process that records its starts. Each frontend's test brings its own catalog of
# fleet/apps; the rest of the car is the same for both.
TICKER = """\
import os, time
with open(os.path.join(os.environ["LPAM_ROOT"], "starts"), "a") as f:
    f.write(f"{os.environ['LPAM_APP']} {os.getpid()}\\n")
while True:
    time.sleep(0.2)
"""


def field_state(port: int) -> str:
    """`fleet/apps` at main (GitHub shorthand sent to the daemon on `port`), app ticker;
    written in a style of its own, whose comments and layout an edit must keep."""
    return f"""\
# The car's apps; edited by libpanda-app-manager and the phone.
version: 1
mirrors:
  "https://github.com/": "git://127.0.0.1:{port}/"
repositories:
# the default apps, listed the way this file's author likes: dashes at the key's column
- repo: fleet/apps
  ref: main   # follow the branch, whatever moves on it: a comment no writer may re-wrap
app:
  name: ticker
# end of file
"""


GADGET = """\
apps:
  - name: gadget
    command: [python3, -u, run.py]
    health: {settle_seconds: 0.5}
"""


def field_repos(make_repo: Callable[[str], RepoBuilder], catalog: str,
                files: Mapping[str, str]) -> None:
    """The GitHub repositories a frontend works with: `fleet/apps` (field_state's) at main,
    `catalog` with `files` (scripts, `*.sh`, executable); and `extra/tools`, no apps on main
    and the app gadget on its branch dev, the repository a frontend adds and removes."""
    apps = make_repo("fleet/apps")
    apps.write("libpanda-apps.yaml", catalog)
    for path, text in files.items():
        apps.write(path, text, executable=path.endswith(".sh"))
    apps.commit("the apps the car runs")
    apps.push()
    tools = make_repo("extra/tools")
    tools.commit("no apps on main")
    tools.branch("dev")
    tools.switch("dev")
    tools.commit("gadget", {"libpanda-apps.yaml": GADGET, "gadget/run.py": TICKER,
                            "gadget/description.txt": "a gadget\n"})
    tools.push()


class FieldCar:
    """A car under `root` as a frontend's test checks it: the real lpam on its root and the
    desired state that the frontend edits."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.lpam = Lpam(root)
        self.desired = root / "etc/lpam/desired-state.yaml"

    def app(self) -> dict[str, Any]:
        """The installed app as `lpam status` reports it; a test that asks expects one."""
        found: dict[str, Any] | None = self.lpam.status()["app"]
        assert found is not None, "no app is installed"
        return found


@contextlib.contextmanager
def applied(car: FieldCar, port: int) -> Iterator[None]:
    """`car` with field_state(port) applied (the daemon on `port` serves field_repos) for
    the block; this root's supervisord, and so the app, stopped by its pid at the end."""
    car.desired.parent.mkdir(parents=True, exist_ok=True)
    car.desired.write_text(field_state(port))
    try:
        done = car.lpam("apply", "--yes")
        assert done.returncode == 0, done.stderr
        yield
    finally:
        shutdown(Layout(car.root))
