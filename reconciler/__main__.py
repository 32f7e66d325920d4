"""`python -m reconciler` is the same as the `lpam` console script."""

from reconciler.cli import main

raise SystemExit(main())
