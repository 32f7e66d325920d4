"""`python -m reconciler` and the `lpam` console script.

The CLI is imported inside `main`, so that a Ctrl-C while Python is still importing lpam
(a slow Pi, a busy machine) ends as an interrupt with exit code 130, not as a traceback.
`lpam --version` and `lpam --help` alone are answered here, before the CLI is imported
(argparse, the layout, the console: about 60 ms on this machine, several times the
interpreter's own start): the version in the words argparse's version action prints, the
help from the text argparse prints, kept in reconciler/frontends/help.txt.
"""

from __future__ import annotations

import sys

# Imported inside functions: --version and --help are answered before the CLI is
# imported, and a Ctrl-C while importing it ends as exit 130 (start-up; see the docstring).


def main() -> int:
    if sys.argv[1:] == ["--version"]:
        from reconciler import __version__

        print(f"lpam {__version__}")
        return 0
    if sys.argv[1:] in (["--help"], ["-h"]):
        from reconciler.frontends.helptext import stored

        text = stored()
        if text is not None:
            sys.stdout.write(text)
            return 0
    try:
        from reconciler.frontends.cli import entry
    except KeyboardInterrupt:
        print("interrupted: lpam was still starting; nothing was changed", file=sys.stderr)
        return 130
    return entry()


if __name__ == "__main__":
    raise SystemExit(main())
