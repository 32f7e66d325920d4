"""How long the long-run tests run: the small numbers of every test run, or the full length
of the last long run in docs/reliability.md.

`LPAM_LONG=1` switches every long-run knob to its full length at once (the run before a
release); a knob's own variable (`LPAM_FAULT_ROUNDS=40`, say) still wins over both.

knob (variable)          normal   LPAM_LONG=1   test
LPAM_FUZZ_EXAMPLES          150        10,000   tests/fuzz/test_documents.py, per kind
LPAM_PROPERTY_EXAMPLES      150         3,000   tests/unit/test_convergence.py
                                        1,000   tests/unit/test_several_apps.py
LPAM_CRASH_INSTANTS           6           240   tests/reliability/test_kills.py
LPAM_FAULT_ROUNDS             6           200   tests/reliability/test_faults.py
LPAM_SEVERAL_ROUNDS           4           120   tests/reliability/test_several_kills.py
LPAM_CONSISTENCY_EXAMPLES   500         5,000   tests/reliability/test_consistency.py (in-process)
LPAM_CONSISTENCY_ROUNDS       4            40   tests/reliability/test_consistency.py (real)
"""

from __future__ import annotations

import os

LONG = os.environ.get("LPAM_LONG", "").strip() not in ("", "0")


def knob(name: str, normal: int, long: int) -> int:
    """The environment variable `name` when it is set; else `long` under LPAM_LONG=1, else
    `normal`."""
    value = os.environ.get(name, "").strip()
    if value:
        return int(value)
    return long if LONG else normal
