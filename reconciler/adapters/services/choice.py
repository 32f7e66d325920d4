"""Which service manager runs the apps: systemd on a vehicle, supervisord elsewhere.

`--services` wins, then the environment variable LPAM_SERVICES, then the machine: systemd
when it is this machine's init (it then has `/run/systemd/system`, the test sd_booted(3)
documents), else supervisord, which lpam starts itself. The check looks at the host, not
under `--root`: a root only moves lpam's files, systemd runs (or not) on the machine.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from reconciler.base.errors import ServiceError
from schemas.kinds import ServiceKind

BACKENDS = tuple(kind.value for kind in ServiceKind)
ENV_VAR = "LPAM_SERVICES"
SYSTEMD_BOOTED = Path("/run/systemd/system")


def choose(
    *, override: str | None, env: Mapping[str, str], booted: Path = SYSTEMD_BOOTED,
) -> ServiceKind:
    """`systemd` or `supervisor`. ServiceError when the flag or variable names neither."""
    for source, value in (("--services", override), (ENV_VAR, env.get(ENV_VAR))):
        if value is None or value == "":
            continue
        if value not in BACKENDS:
            raise ServiceError(
                f"{source}={value!r} names no service manager lpam knows",
                hint=f"use {' or '.join(BACKENDS)}, or leave {source} unset to use systemd "
                "where it runs and supervisord elsewhere",
            )
        return ServiceKind(value)
    return ServiceKind.SYSTEMD if booted.is_dir() else ServiceKind.SUPERVISOR
