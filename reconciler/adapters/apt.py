"""System packages through dpkg and apt, the way a careful administrator would run them.

- `dpkg-query` decides what is missing (a package counts as present only when dpkg says
  it is fully installed: `ii`), so nothing runs when everything is there;
- one batched `apt-get install -y --no-install-recommends` for the missing ones only,
  non-interactive (no debconf question may hang an unattended car);
- `apt-get update` once, only when the install says a package cannot be found: the
  package lists of a car that was offline for weeks are stale, but refreshing them on
  every apply would cost minutes of bad WiFi for nothing.

Both programs are found on PATH and given argument lists; the names were validated
against Debian's grammar (schemas/dependency.py) before they got here.
"""

from __future__ import annotations

import os
import re
import subprocess
import time
from collections.abc import Sequence

from reconciler.adapters.command import run_streamed
from reconciler.base.errors import DependencyError
from reconciler.engine.execution.ports import Log

_NOT_FOUND = re.compile(r"Unable to locate package|has no installation candidate")
_APT_ENV = {"DEBIAN_FRONTEND": "noninteractive", "APT_LISTCHANGES_FRONTEND": "none"}


class AptPackages:
    """The `Packages` port on a Debian system."""

    def __init__(self, *, timeout: float = 3600.0) -> None:
        self._timeout = timeout

    def missing(self, names: Sequence[str]) -> list[str]:
        """The names dpkg does not list as installed, in the order given."""
        if not names:
            return []
        result = subprocess.run(
            ["dpkg-query", "-W", "-f=${Package}\t${db:Status-Abbrev}\n", *names],
            capture_output=True, text=True, timeout=60, check=False,
        )
        fields = (line.partition("\t") for line in result.stdout.splitlines())
        installed = {package for package, _, status in fields if status.startswith("ii")}
        return [name for name in names if name.split(":")[0] not in installed]

    def install(self, names: Sequence[str], *, log: Log) -> None:
        """Install `names` in one batch; DependencyError naming them when apt cannot."""
        if not names:
            return
        argv = ["apt-get", "install", "-y", "--no-install-recommends", *names]
        code, tail = self._run(argv, log)
        if code != 0 and any(_NOT_FOUND.search(line) for line in tail):
            update, update_tail = self._run(["apt-get", "update"], log)
            if update != 0:
                raise DependencyError(
                    f"apt-get update failed (exit {update}) while looking for "
                    f"{', '.join(names)}", details=update_tail,
                    hint="check the network or the apt sources; the running app is untouched",
                )
            code, tail = self._run(argv, log)
        if code != 0:
            cause = next((line for line in reversed(tail) if line.startswith("E:")),
                         f"exit {code}")
            raise DependencyError(
                f"apt-get could not install {', '.join(names)}: {cause}", details=tail,
                hint="check the package names in the app's catalog and the apt sources; the "
                "running app is untouched",
            )

    def _run(self, argv: list[str], log: Log) -> tuple[int, list[str]]:
        """Run one apt-get, its output streamed to `log`; (exit code, last lines)."""
        outcome = run_streamed(argv, log=log, deadline=time.monotonic() + self._timeout,
                               env={**os.environ, **_APT_ENV})
        if outcome.code == 127 and outcome.tail[-1].startswith("cannot run"):
            raise DependencyError(f"{outcome.tail[-1]}", hint="lpam installs apt packages "
                                  "on Debian systems only")
        if outcome.code is None:
            raise DependencyError(
                f"{' '.join(argv[:2])} did not finish within {self._timeout:g} s and was "
                "killed", details=outcome.tail,
                hint="check the network and apt's locks; the running app is untouched")
        return outcome.code, outcome.tail
