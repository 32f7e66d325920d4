"""Whether a process runs, asked of the kernel: for what lpam keeps by pid (its
supervisord, the lpam process of an apply in progress)."""

from __future__ import annotations

import os
from pathlib import Path


def alive(pid: int) -> bool:
    """True while `pid` runs; a zombie (PID 1 here may never reap one) is not running."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        fields = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return fields.rsplit(")", 1)[-1].split()[:1] != ["Z"]
