"""`python -m reconciler` is the same as the `lpam` console script."""

from reconciler.cli import entry

raise SystemExit(entry())
