"""App catalogs as parsed before, kept beside the checkout they were read from.

Why: `lpam status` (and the phone's app table, and the shim's `-d` built on it) lists every
repository's apps, and a no-op `lpam plan` reads every catalog again: 20 repositories
meant 20 compositions of YAML by ruamel.yaml's round-trip parser (pure Python, ~5-30 ms
a catalog here, several times that on a Pi) to learn what did not change. A catalog that
parsed cleanly is kept as the JSON of the validated model, named by the SHA-256 of its
text and lpam's version, so a hit is exactly what parsing would give: the same text,
the same code. Reading a hit is `json` and the model's validation.

Where: in the checkout's `.git` (`lpam-catalog-<digest>.json`), beside `lpam-verified.json`
(adapters/integrity.py): written by lpam only, as root on a car, under var/lib/lpam whose
state record lpam already trusts; gone with the checkout when it is fetched anew. A
catalog that does not parse is never kept (its error is made again, with its position),
and a cached file that does not validate is ignored and written anew. Failing to write
(a read-only store, a user's status) only costs the speed.
"""

from __future__ import annotations

import contextlib
import hashlib
from pathlib import Path

from reconciler import __version__
from reconciler.base.atomic import write_atomic
from reconciler.core.documents import parse_catalog
from schemas.catalog import Catalog

PREFIX = "lpam-catalog-"


def parsed(checkout: Path, label: Path, data: bytes) -> Catalog:
    """The catalog `data` (the bytes of libpanda-apps.yaml at some commit of the checkout
    `checkout`), parsed, from the cache when this lpam parsed the same text before;
    ConfigError (at its line and column) when it does not parse."""
    git = checkout / ".git"
    digest = hashlib.sha256(__version__.encode() + b"\0" + data).hexdigest()
    kept = git / f"{PREFIX}{digest}.json"
    with contextlib.suppress(OSError, ValueError):
        return Catalog.model_validate_json(kept.read_bytes())
    catalog = parse_catalog(label, data.decode("utf-8", "replace"))
    if git.is_dir():
        with contextlib.suppress(OSError):
            write_atomic(kept, catalog.model_dump_json().encode())
    return catalog
