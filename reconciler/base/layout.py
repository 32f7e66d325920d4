"""Every path lpam touches, derived from one root.

Tests and the demo pass `--root DIR` (or LPAM_ROOT) so that nothing outside DIR is ever
written; on a vehicle the root is `/`. No other module joins paths onto the root itself.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")
_GENERATION = re.compile(r"[0-9a-f]{12}-[0-9a-f]{8}")
_RUN = re.compile(r"[0-9a-f]{32}")

KEEP_GENERATIONS = 3
"""Good generations kept on disk for `lpam rollback` unless `--keep-generations` says
otherwise: the installed one and the two before it."""


@dataclass(frozen=True)
class Layout:
    """The file system map of one lpam installation."""

    root: Path

    @property
    def etc(self) -> Path:
        return self.root / "etc" / "lpam"

    @property
    def desired_state(self) -> Path:
        """Where `plan` and `apply` look when no `-f FILE` is given."""
        return self.etc / "desired-state.yaml"

    @property
    def agent_config(self) -> Path:
        """How this vehicle follows a desired-state repository (`lpam sync`, `lpam agent`)."""
        return self.etc / "agent.yaml"

    @property
    def var(self) -> Path:
        return self.root / "var" / "lib" / "lpam"

    @property
    def repositories(self) -> Path:
        """The repository store: one git checkout per app repository."""
        return self.var / "repositories"

    @property
    def generations(self) -> Path:
        """Immutable copies of app folders, one directory per generation."""
        return self.var / "generations"

    @property
    def state_record(self) -> Path:
        return self.var / "state.json"

    @property
    def runs(self) -> Path:
        """Exit codes of app scripts, written by each script's guard when it ends."""
        return self.var / "runs"

    def run_result(self, run: str) -> Path:
        if not _RUN.fullmatch(run):
            raise ValueError(f"not a script run id: {run!r}")
        return self.runs / f"{run}.exit"

    @property
    def journal(self) -> Path:
        return self.var / "journal.jsonl"

    @property
    def lock(self) -> Path:
        return self.var / "apply.lock"

    @property
    def logs(self) -> Path:
        return self.root / "var" / "log" / "lpam"

    @property
    def debug_log(self) -> Path:
        return self.logs / "debug.log"

    @property
    def app_logs(self) -> Path:
        """The output of each app supervisord runs (systemd keeps it in its journal)."""
        return self.logs / "apps"

    @property
    def run_dir(self) -> Path:
        """`/run/lpam`: runtime files that mean nothing after a reboot (a tmpfs there)."""
        return self.root / "run" / "lpam"

    @property
    def ble_service(self) -> Path:
        """What the running `lpam ble` says of itself: its write mode (schemas/bluetooth.py)."""
        return self.run_dir / "ble.json"

    @property
    def supervisor_dir(self) -> Path:
        """The configuration of the supervisord lpam starts for this root."""
        return self.etc / "supervisor"

    @property
    def supervisor_conf(self) -> Path:
        return self.supervisor_dir / "supervisord.conf"

    @property
    def supervisor_programs(self) -> Path:
        """One `<unit>.conf` per unit lpam installed, included by supervisord.conf."""
        return self.supervisor_dir / "programs"

    def supervisor_program(self, unit: str) -> Path:
        if not unit or "/" in unit or unit.startswith("."):
            raise ValueError(f"not a unit name: {unit!r}")
        return self.supervisor_programs / f"{unit}.conf"

    @property
    def supervisor_socket(self) -> Path:
        return self.run_dir / "supervisor.sock"

    @property
    def supervisor_pid(self) -> Path:
        return self.run_dir / "supervisord.pid"

    @property
    def supervisor_lock(self) -> Path:
        """Held while one lpam process checks for and starts supervisord."""
        return self.run_dir / "supervisord.lock"

    @property
    def supervisor_starts(self) -> Path:
        """Where in supervisord's log each unit was last started by lpam (restart counts)."""
        return self.run_dir / "starts"

    @property
    def supervisor_log(self) -> Path:
        return self.logs / "supervisord.log"

    @property
    def libpanda(self) -> Path:
        """LPAM's folder (`/etc/libpanda.d`): the field's scripts look for apps under it."""
        return self.root / "etc" / "libpanda.d"

    @property
    def libpanda_apps(self) -> Path:
        return self.libpanda / "apps"

    def app_link(self, folder: str) -> Path:
        """`/etc/libpanda.d/apps/<folder>`: the installed generation, where LPAM put apps."""
        if folder != slug(folder):
            raise ValueError(f"not an app folder name: {folder!r}")
        return self.libpanda_apps / folder

    @property
    def systemd_units(self) -> Path:
        """Where the systemd adapter writes the units of scriptless apps (the directory for
        the administrator's units, which outranks the packages' /lib/systemd/system)."""
        return self.root / "etc" / "systemd" / "system"

    @property
    def replaced(self) -> Path:
        """LPAM's own copies of app folders, kept when lpam puts its link in their place."""
        return self.var / "replaced"

    @property
    def agent_status(self) -> Path:
        """What the agent's passes found and did (schemas/agent.py `AgentStatus`)."""
        return self.var / "status.json"

    @property
    def thermal_zone(self) -> Path:
        """The CPU's temperature in millidegrees Celsius, as the kernel gives it."""
        return self.root / "sys" / "class" / "thermal" / "thermal_zone0" / "temp"

    @property
    def override(self) -> Path:
        """A local edit that overrides the fleet's desired state (schemas/override.py)."""
        return self.var / "override.json"

    @property
    def override_ended(self) -> Path:
        """The local desired-state file an ended override set aside, for the record."""
        return self.var / "override-ended.yaml"

    @property
    def agent_files(self) -> Path:
        """Files a followed desired state names relative to itself (a DBC, a CAN log),
        copied out of the source: `<revision>/<path in the source>`."""
        return self.var / "agent-files"

    def under(self, path: str) -> Path:
        """A machine path as documents write it (`/run/lpam/locks/x.lock`), under --root."""
        return self.root / path.lstrip("/")

    @property
    def venvs(self) -> Path:
        """Virtual environments of apps' pip requirements, one per set of requirements."""
        return self.var / "venvs"

    def home(self, user: str) -> Path:
        """A user's home as the field's scripts know it (`/home/<user>`, `/root` for root)."""
        if not user or user != slug(user):
            raise ValueError(f"not a user name: {user!r}")
        return self.root / "root" if user == "root" else self.root / "home" / user

    def repository_dir(self, key: str) -> Path:
        """The checkout of the repository known as `key` (e.g. `owner/name`)."""
        return self.repositories / slug(key)

    def generation_dir(self, app: str, generation: str) -> Path:
        if not _GENERATION.fullmatch(generation):
            raise ValueError(f"not a generation id: {generation!r}")
        return self.generations / slug(app) / generation

    def generation_meta(self, app: str, generation: str) -> Path:
        """What was staged into the generation (engine/records/generations.py), beside it."""
        return self.generation_dir(app, generation).with_suffix(".json")


def is_generation_id(name: str) -> bool:
    return _GENERATION.fullmatch(name) is not None


def slug(key: str) -> str:
    """A single, safe path component for a repository key or app name."""
    cleaned = _UNSAFE.sub("+", key.replace("/", "+")).strip(".")
    return cleaned or "_"
