"""The demo: build an example app repository, then drive lpam through a whole life cycle.

Everything happens under `.demo/` (the sandbox root is `.demo/root`): nothing outside the
checkout is touched and no network is used. Run it with `bash scripts/dev demo`.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from dulwich import porcelain
from dulwich.repo import Repo
from ruamel.yaml import YAML

HERE = Path(__file__).resolve().parent
TOP = HERE.parent
sys.path.insert(0, str(TOP))
from tests.wheels import write_wheel  # noqa: E402 - after the checkout is on sys.path

DEMO = TOP / ".demo"
ROOT = DEMO / "root"
REPO = DEMO / "example-apps.git"
EXAMPLE = TOP / "desired-state.example.yaml"
WHEELS = DEMO / "wheels"
LPAM = [sys.executable, "-m", "reconciler"]
IDENTITY = b"lpam demo <demo@example.org>"


def build_repository() -> str:
    """A real git repository of the example apps: two commits on `main`, a tag v1.0."""
    work = DEMO / "example-apps-work"
    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(HERE / "example-apps", work)
    repo = porcelain.init(str(work))
    files = [str(p) for p in work.rglob("*") if p.is_file() and ".git" not in p.parts]
    porcelain.add(repo, paths=files)
    porcelain.commit(repo, message=b"Example apps: can-logger and speed-monitor",
                     author=IDENTITY, committer=IDENTITY)
    porcelain.tag_create(repo, b"v1.0", author=IDENTITY, message=b"first release", annotated=True)
    notes = work / "speed-monitor" / "description.txt"
    notes.write_text("Prints the vehicle speed (km/h) from CAN message 0xB4\n")
    porcelain.add(repo, paths=[str(notes)])
    head = porcelain.commit(repo, message=b"speed-monitor: say the unit", author=IDENTITY,
                            committer=IDENTITY)
    if Repo(str(work)).refs.read_ref(b"HEAD") != b"ref: refs/heads/main":
        Repo(str(work)).refs.set_symbolic_ref(b"HEAD", b"refs/heads/main")
        Repo(str(work)).refs[b"refs/heads/main"] = head
    shutil.rmtree(REPO, ignore_errors=True)
    with open(os.devnull, "wb") as quiet:
        porcelain.clone(str(work), str(REPO), bare=True, errstream=quiet)
    shutil.rmtree(work)
    return head.decode()


def build_wheels() -> str:
    """The wheel folder the apps' pip dependency comes from (no index, no network): the
    module examples/speedunits.py as the distribution lpam-demo-speedunits."""
    shutil.rmtree(WHEELS, ignore_errors=True)
    WHEELS.mkdir(parents=True)
    wheel = write_wheel(WHEELS, "lpam-demo-speedunits", "1.0", module="speedunits",
                        source=(HERE / "speedunits.py").read_text())
    return wheel.name


FLEET = DEMO / "fleet.git"


def build_fleet(desired: str) -> Path:
    """The lab's desired-state repository: `desired-state.yaml` for every car, its app
    repository named relative to it (`../example-apps.git`, as git resolves submodules)."""
    shutil.rmtree(FLEET, ignore_errors=True)
    porcelain.init(str(FLEET), bare=True)
    Repo(str(FLEET)).refs.set_symbolic_ref(b"HEAD", b"refs/heads/main")  # what clones get
    commit_to_fleet(desired.replace(f"url: {REPO.name}", "url: ../example-apps.git"),
                    "the lab's first desired state")
    return FLEET


def commit_to_fleet(desired: str, message: str) -> None:
    """Commit `desired` as desired-state.yaml on the fleet repository's main branch."""
    work = DEMO / "fleet-work"
    shutil.rmtree(work, ignore_errors=True)
    with open(os.devnull, "wb") as quiet:
        repo = porcelain.clone(str(FLEET), str(work), errstream=quiet)
    (work / "desired-state.yaml").write_text(desired)
    porcelain.add(repo, paths=[str(work / "desired-state.yaml")])
    porcelain.commit(repo, message=message.encode(), author=IDENTITY, committer=IDENTITY)
    with open(os.devnull, "wb") as quiet:
        porcelain.push(repo, str(FLEET), b"HEAD:refs/heads/main", errstream=quiet)
    shutil.rmtree(work)


def lpam(*args: str, check: bool = True) -> int:
    shown = " ".join(["lpam", *args]).replace(str(TOP) + "/", "")
    print(f"\n$ {shown}", flush=True)
    # supervisord under the sandbox root runs the apps, even on a machine where systemd
    # runs: the demo must never touch this machine's own services.
    # pip installs the apps' dependencies from the demo's wheel folder only.
    env = dict(os.environ, LPAM_ROOT=str(ROOT), LPAM_SERVICES="supervisor", PIP_NO_INDEX="1",
               PIP_FIND_LINKS=str(WHEELS), PIP_DISABLE_PIP_VERSION_CHECK="1")
    code = subprocess.call([*LPAM, *args], cwd=TOP, env=env)
    if check and code not in (0, 2):
        raise SystemExit(f"demo failed: `{shown}` exited {code}")
    return code


def lpam_says(*args: str) -> str:
    """`lpam(*args)`, its output shown as ever and returned, for the demo to check."""
    shown = " ".join(["lpam", *args]).replace(str(TOP) + "/", "")
    print(f"\n$ {shown}", flush=True)
    env = dict(os.environ, LPAM_ROOT=str(ROOT), LPAM_SERVICES="supervisor")
    done = subprocess.run([*LPAM, *args], cwd=TOP, env=env, capture_output=True, text=True,
                          check=False)
    print(done.stdout, end="", flush=True)
    print(done.stderr, end="", file=sys.stderr, flush=True)
    if done.returncode not in (0, 2):
        raise SystemExit(f"demo failed: `{shown}` exited {done.returncode}")
    return done.stdout


def switched_desired_state(app: str, params: dict[str, str], name: str,
                           **extra: object) -> Path:
    """The example desired state with another app, comments kept (round-trip YAML)."""
    yaml = YAML()
    data = yaml.load(EXAMPLE.read_text())
    data["app"]["name"] = app
    data["app"]["params"] = params
    data.update(extra)
    data["repositories"][0]["url"] = REPO.name  # relative to the new file's folder
    path = DEMO / f"desired-state.{name}.yaml"
    with path.open("w") as out:
        yaml.dump(data, out)
    return path


def main() -> int:
    if ROOT.exists():  # a previous demo's supervisord, if it was left running
        subprocess.call([*LPAM, "--root", str(ROOT), "services", "shutdown"],
                        stdout=subprocess.DEVNULL)
    shutil.rmtree(ROOT, ignore_errors=True)
    DEMO.mkdir(exist_ok=True)
    print("== 1. Build the example app repository (.demo/example-apps.git)")
    print(f"   main is at {build_repository()[:12]}; tag v1.0 on the commit before")
    print(f"   the apps' pip dependency: .demo/wheels/{build_wheels()} (no index, no network)")
    print("\n== 2. Validate and preview the example desired state")
    lpam("validate", str(EXAMPLE))
    lpam("plan", "-f", str(EXAMPLE))
    print("\n== 3. Apply it: clone, prepare can-logger's Python environment from the wheel")
    print("   folder (before the cutover), stage, install and start it")
    lpam("apply", "-f", str(EXAMPLE), "--yes")
    lpam("status")
    print("\n== 4. Plan again: nothing to do (exit code 0 with --detailed-exitcode)")
    code = lpam("plan", "-f", str(EXAMPLE), "--detailed-exitcode")
    print(f"   (exit code {code}: 0 means no changes)")
    print("\n== 5. Switch the app: can-logger is stopped and uninstalled before speed-monitor")
    other = switched_desired_state("speed-monitor", {"SPEED_UNIT": "km/h"}, "switched")
    lpam("plan", "-f", str(other))
    started = time.monotonic()
    lpam("apply", "-f", str(other), "--yes")
    print(f"   (apply took {time.monotonic() - started:.2f} s)")
    lpam("status")
    running = sorted(p.name for p in (ROOT / "run" / "lpam-demo").glob("*.running"))
    print(f"\n   running markers under the sandbox root: {running}")
    if running != ["speed-monitor.running"]:
        raise SystemExit("demo failed: expected exactly speed-monitor to run")
    print("\n== 6. A bad desired state is refused with file:line:column; nothing changes")
    bad = DEMO / "bad.yaml"
    bad.write_text("version: 1\nrepositories:\n  - url: x\n    reff: main\napp: null\n")
    lpam("plan", "-f", str(bad), check=False)
    print("\n== 7. A scriptless app: lpam writes its unit and supervisord runs it, inside")
    print("   its Python environment (shared with can-logger: same requirements, no pip run)")
    logger = switched_desired_state("speed-logger", {"RATE_HZ": "4"}, "logger")
    lpam("apply", "-f", str(logger), "--yes")
    lpam("status")
    time.sleep(1)
    lpam("logs", "-n", "3")
    print("\n== 8. A broken release: the new version crashes after a second; the health")
    print("   check catches it and lpam rolls back to the version that worked (exit 3)")
    broken = switched_desired_state("speed-logger", {"RATE_HZ": "4", "CRASH_AFTER": "1"},
                                    "broken")
    code = lpam("apply", "-f", str(broken), "--yes", check=False)
    if code != 3:
        raise SystemExit(f"demo failed: the broken release should exit 3, not {code}")
    lpam("status", "--json")
    lpam("history")
    print("\n== 9. Follow a desired-state repository, as a car does: the lab commits the")
    print("   desired state, the car's agent applies it (one pass: `lpam sync`)")
    fleet = build_fleet(switched_desired_state("speed-monitor", {"SPEED_UNIT": "mph"},
                                               "fleet").read_text())
    agent = ROOT / "etc" / "lpam" / "agent.yaml"
    agent.write_text(f"version: 1\nsource: {{url: '{fleet}', branch: main}}\n"
                     "vehicle: demo-car\n")
    lpam("sync")
    lpam("status")
    print("\n   A broken commit is refused, the app keeps running, and it is not retried:")
    commit_to_fleet("version: 1\napp: {name: speed-monitor, parmas: {}}\n", "typo")
    lpam("sync", check=False)
    lpam("sync")
    print("\n== 10. Update gates: the switch waits until the car is parked. A RAV4 drive")
    print("   generated from a speed profile (tests/drive.py) is replayed as the CSV the")
    print("   recording app writes")
    gates_on_the_drive()
    print("\n== 11. Stop supervisord (and the app it runs)")
    lpam("services", "shutdown")
    print("\nDemo complete. The sandbox root is .demo/root; rerun to start afresh.")
    return 0


def drive_at(instant: float) -> None:
    """The recording app's CSV as it stands `instant` seconds into the generated drive, this
    instant being now, behind /etc/libpanda.d/currentCan.csv."""
    from tests.canlog import between, drive, write_csv

    frames = drive()
    data = ROOT / "var" / "log" / "demo-drive" / f"at-{instant:g}.csv"
    data.parent.mkdir(parents=True, exist_ok=True)
    write_csv(data, between(frames, max(0.0, instant - 120), instant),
              shift=time.time() - (frames[0].timestamp + instant))
    link = ROOT / "etc" / "libpanda.d" / "currentCan.csv"
    link.parent.mkdir(parents=True, exist_ok=True)
    link.unlink(missing_ok=True)
    link.symlink_to(data)


def gates_on_the_drive() -> None:
    drive_at(200.0)
    gated = switched_desired_state("can-logger", {"LOG_RATE_HZ": "10"}, "gated",
                                   gates={"stationary_seconds": 60})
    print("   200 s into the drive the car is moving: the switch is prepared, then deferred")
    code = lpam("apply", "-f", str(gated), "--yes", check=False)
    if code != 75:
        raise SystemExit(f"demo failed: a moving car should defer the switch (75), not {code}")
    said = lpam_says("status")
    if "Last apply: deferred" not in said or "cut off" in said:
        raise SystemExit("demo failed: status should show the switch as deferred by the "
                         "gates, not as cut off")
    print("\n   740 s into the drive it has stood since 668.75 s: parked, the switch goes through")
    drive_at(740.0)
    lpam("gates", "-f", str(gated))
    lpam("apply", "-f", str(gated), "--yes")


if __name__ == "__main__":
    sys.exit(main())
