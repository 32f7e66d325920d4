"""`python -m reconciler` and the `lpam` console script.

The CLI is imported inside `main`, so that a Ctrl-C while Python is still importing lpam
(a slow Pi, a busy machine) ends as an interrupt with exit code 130, not as a traceback.
"""

from __future__ import annotations

import sys


def main() -> int:
    try:
        from reconciler.frontends.cli import entry
    except KeyboardInterrupt:
        print("interrupted: lpam was still starting; nothing was changed", file=sys.stderr)
        return 130
    return entry()


if __name__ == "__main__":
    raise SystemExit(main())
