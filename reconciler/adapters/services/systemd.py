"""The `Services` port on systemd: the service manager of a vehicle's Raspberry Pi.

lpam writes the unit of a scriptless app itself (reconciler/adapters/services/unitfile.py)
to `/etc/systemd/system/<name>.service` and drives systemd with `systemctl` and
`journalctl`: argument lists only (never a shell), a unit name always after `--`, a time
limit on every call, its standard input closed (no password prompt can hang an apply).

Installing also *enables* the unit (`WantedBy=multi-user.target`): the ignition cuts the
power without warning, and the installed app must run again when the Pi boots, without
lpam. Starting and stopping stay separate acts (`systemctl start|stop`), so that the
cutover (stop old, uninstall old, install new, start new) decides when an app runs and an
operator's `lpam stop` lasts until the next boot at most. Uninstalling undoes all of it:
stop, `disable`, remove the file, `daemon-reload`.

Power can fail between any two of these calls, so each step looks before it acts:
`install` reloads systemd when the file changed *or* systemd says its loaded copy is stale
(a reload cut short), and enables every time (enabling an enabled unit changes nothing);
`uninstall` acts on a file lpam wrote or on a unit systemd still has loaded from it, and
is a no-op once both are gone. A unit file without lpam's header line was not written by
lpam and is never replaced or removed.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from reconciler.adapters.services.unitfile import HEADER, render_unit
from reconciler.base.atomic import fsync_dir, write_atomic
from reconciler.base.errors import ServiceError, shorten
from reconciler.base.layout import Layout
from reconciler.base.reading import MIB, read_bounded
from reconciler.base.unit import Unit, UnitState, check_unit_name
from reconciler.engine.execution.ports import DEFAULT_PATH
from reconciler.engine.observe.unit_state import SHOW_PROPERTIES, parse_properties, parse_show

ACT_TIMEOUT = 90.0  # start, stop, restart, (dis|en)able, daemon-reload: systemd waits for jobs
QUERY_TIMEOUT = 15.0  # show
JOURNAL_TIMEOUT = 30.0  # a large journal on an SD card is slow to seek
UNIT_FILE_LIMIT = 16 * MIB
DETAIL_LIMIT = 300  # characters of a failed command's output kept in its error
NO_SYSTEMD_HINT = ("this machine does not seem to run systemd; use `--services supervisor` "
                   "(or LPAM_SERVICES=supervisor)")


class SystemdServices:
    """Units in `<root>/etc/systemd/system`, run by the host's systemd. On a vehicle the
    root is `/`; under another root the unit files land there, but `systemctl` still
    speaks to this machine's systemd, so tests give it a fake `systemctl` on PATH."""

    kind = "systemd"

    def __init__(
        self, layout: Layout, *, systemctl: str | None = None, journalctl: str | None = None,
        act_timeout: float = ACT_TIMEOUT, query_timeout: float = QUERY_TIMEOUT,
    ) -> None:
        self.layout = layout
        self._tools = {"systemctl": systemctl, "journalctl": journalctl}
        self.act_timeout = act_timeout
        self.query_timeout = query_timeout

    # -- the port ---------------------------------------------------------------------

    def check(self, unit: Unit) -> None:
        """The unit renders, and `systemd-analyze verify` (where it is installed) has
        nothing to say about it: checked in a temporary folder, offline, before cutover."""
        name = _unit(unit.name)
        text = self._render(unit)
        analyze = shutil.which("systemd-analyze")
        if analyze is None:
            return
        with tempfile.TemporaryDirectory(prefix="lpam-verify-") as tmp:
            path = Path(tmp) / name
            path.write_text(text)
            try:
                done = subprocess.run([analyze, "verify", str(path)], capture_output=True,
                                      timeout=self.query_timeout, stdin=subprocess.DEVNULL)
            except subprocess.TimeoutExpired:
                raise ServiceError(f"systemd-analyze verify of {name} did not finish within "
                                   f"{self.query_timeout:g} s") from None
        said = _said(done.stderr).replace(str(path), name)
        if done.returncode != 0 or said:
            raise ServiceError(f"the systemd unit {name} does not verify: "
                               f"{said or done.returncode}",
                               hint="fix the app's command, user or parameters: lpam "
                               "writes the unit from them")

    def _render(self, unit: Unit) -> str:
        try:
            return render_unit(_resolved(unit))
        except ValueError as exc:
            raise ServiceError(
                f"cannot write the systemd unit {_unit(unit.name)}: {exc}",
                hint="change the app's command or parameters so that they hold no such "
                "value, then apply again",
            ) from None

    def install(self, unit: Unit) -> None:
        self._put(_unit(unit.name), self._render(unit))

    def install_text(self, name: str, text: str, *, start: bool = False) -> None:
        """Install a unit lpam wrote itself that is not an app's (the agent's), enabled,
        and started when `start`."""
        unit = _unit(name)
        self._put(unit, text, reload=True)
        if start:
            self._systemctl("start", "--", unit, unit=unit)

    def uninstall(self, name: str) -> None:
        unit = _unit(name)
        path = self.unit_file(name)
        written = self._ours(path) is not None
        text = self._show(unit, (*SHOW_PROPERTIES, "FragmentPath"))
        state = self._parse(unit, text)
        loaded_from_ours = state.known and parse_properties(text).get("FragmentPath") == str(path)
        if not written and not loaded_from_ours:
            return
        if state.known:
            if state.active not in ("inactive", "failed"):
                self._systemctl("stop", "--", unit, unit=unit)
            # A unit left failed would keep the machine "degraded" after its file is gone.
            with contextlib.suppress(ServiceError):
                self._systemctl("reset-failed", "--", unit, unit=unit)
        if written:
            self._systemctl("--no-reload", "disable", "--", unit, unit=unit)
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
            fsync_dir(path.parent)
        self._systemctl("daemon-reload", unit=unit)

    def start(self, name: str) -> None:
        unit = _unit(name)
        self._systemctl("start", "--", unit, unit=unit)

    def stop(self, name: str) -> None:
        """Stop `name`; a unit systemd does not know is stopped already (a stop repeated
        after an interrupted uninstall must not fail the apply)."""
        unit = _unit(name)
        try:
            self._systemctl("stop", "--", unit, unit=unit)
        except ServiceError:
            if self.state(name).known:
                raise

    def restart(self, name: str) -> None:
        unit = _unit(name)
        self._systemctl("restart", "--", unit, unit=unit)

    def state(self, name: str) -> UnitState:
        unit = _unit(name)
        return self._parse(unit, self._show(unit, SHOW_PROPERTIES))

    def logs(self, name: str, lines: int = 20) -> list[str]:
        unit = _unit(name)
        # --quiet: no "-- No entries --" line posing as the app's output.
        out = self._run("journalctl", ["-u", unit, "-n", str(max(lines, 0)), "--no-pager",
                                       "-o", "cat", "--quiet"],
                        unit=unit, timeout=JOURNAL_TIMEOUT)
        return out.splitlines()

    # -- helpers ----------------------------------------------------------------------

    def _put(self, unit: str, text: str, *, reload: bool = False) -> None:
        """Write the file of `unit` when it differs from `text`, have systemd reload when
        it changed or its loaded copy is stale (always with `reload`), and enable it."""
        path = self.layout.systemd_units / unit
        changed = self._ours(path) != text.encode("utf-8")
        if changed:
            write_atomic(path, text)
        if reload or changed or self._stale(unit):
            self._systemctl("daemon-reload", unit=unit)
        self._systemctl("--no-reload", "enable", "--", unit, unit=unit)

    def unit_file(self, name: str) -> Path:
        """Where the unit `name` (with or without `.service`) is written."""
        return self.layout.systemd_units / _unit(name)

    def _ours(self, path: Path) -> bytes | None:
        """The unit file lpam wrote at `path`; None when there is none. ServiceError when
        another hand wrote it: lpam neither replaces nor removes what it did not write."""
        try:
            data = read_bounded(path, limit=UNIT_FILE_LIMIT, follow_symlinks=False,
                                what="systemd unit file")
        except FileNotFoundError:
            return None
        if not data.startswith(HEADER.encode()):
            raise ServiceError(
                f"{path} was not written by lpam; lpam will not replace or remove it",
                hint="if the program it runs is no longer wanted, disable it and move the "
                "file away, then apply again",
            )
        return data

    def _stale(self, unit: str) -> bool:
        """Whether systemd's loaded copy of `unit` may differ from its file on disk."""
        props = parse_properties(self._show(unit, ("LoadState", "NeedDaemonReload")))
        return props.get("LoadState") in (None, "not-found") or \
            props.get("NeedDaemonReload") != "no"

    def _show(self, unit: str, properties: tuple[str, ...]) -> str:
        return self._run("systemctl", ["show", f"--property={','.join(properties)}", "--", unit],
                         unit=unit, timeout=self.query_timeout)

    def _parse(self, unit: str, text: str) -> UnitState:
        try:
            return parse_show(unit.removesuffix(".service"), text)
        except ValueError as exc:
            raise ServiceError(f"systemctl answered nonsense about {unit}: {exc}",
                               hint=NO_SYSTEMD_HINT) from None

    def _systemctl(self, *args: str, unit: str) -> None:
        self._run("systemctl", list(args), unit=unit, timeout=self.act_timeout)

    def _run(self, tool: str, args: list[str], *, unit: str, timeout: float) -> str:
        """Run `tool args` (no shell); its standard output. ServiceError naming the unit
        and quoting what the tool said when it fails or overruns `timeout`."""
        argv = [self._tool(tool), *args]
        command = " ".join([tool, *args])
        try:
            proc = subprocess.run(argv, stdin=subprocess.DEVNULL, capture_output=True,
                                  timeout=timeout, check=False)
        except subprocess.TimeoutExpired:
            raise ServiceError(
                f"`{command}` did not finish within {timeout:g} s ({unit})",
                hint=f"systemd may still be working on it: see `systemctl status {unit}`",
            ) from None
        except OSError as exc:
            raise ServiceError(f"cannot run {argv[0]} for {unit}: {exc.strerror}",
                               hint=NO_SYSTEMD_HINT) from None
        if proc.returncode != 0:
            said = _said(proc.stderr) or _said(proc.stdout) or "(no output)"
            raise ServiceError(f"`{command}` failed with exit code {proc.returncode}: {said}",
                               hint=_hint(said, unit))
        return proc.stdout.decode("utf-8", errors="replace")

    def _tool(self, tool: str) -> str:
        found = self._tools.get(tool) or shutil.which(tool)
        if found is None:
            raise ServiceError(f"{tool} is not on PATH", hint=NO_SYSTEMD_HINT)
        self._tools[tool] = found
        return found


def _unit(name: str) -> str:
    """`name` as a systemd service unit name, checked: one word, never an option or path."""
    try:
        return f"{check_unit_name(name)}.service"
    except ValueError as exc:
        raise ServiceError(str(exc)) from None


def _resolved(unit: Unit) -> Unit:
    """`unit` with a bare program name (`roslaunch`) made absolute, as found on the PATH
    the app gets (else lpam's own): systemd would search only its compiled-in directories.
    """
    program = unit.argv[0] if unit.argv else "/"
    if "/" in program:
        return unit
    path = unit.environment.get("PATH") or os.environ.get("PATH") or DEFAULT_PATH
    found = shutil.which(program, path=path)
    if found is None:
        raise ServiceError(f"{unit.name}: program {program!r} is not on PATH ({path})",
                           hint="install it, or give the app's command as a path")
    return dataclasses.replace(unit, argv=(os.path.abspath(found), *unit.argv[1:]))


def _said(output: bytes) -> str:
    """A command's output as one bounded line for an error message."""
    return shorten(" ".join(output.decode("utf-8", errors="replace").split()), DETAIL_LIMIT)


def _hint(said: str, unit: str) -> str:
    lowered = said.lower()
    if "access denied" in lowered or "authentication" in lowered or "permission" in lowered:
        return "managing system services needs root: run lpam with sudo"
    if "not been booted with systemd" in lowered or "failed to connect to bus" in lowered:
        return NO_SYSTEMD_HINT
    return f"`systemctl status {unit}` and `journalctl -u {unit}` say why"
