"""The import use case (`lpam import-lpam`): a desired state equivalent to what LPAM
installed, shown or written to a new file — never over an existing one."""

from __future__ import annotations

from pathlib import Path

from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.engine.records.legacy import import_lpam


def import_legacy(layout: Layout, etc_dir: Path | None, *, output: Path | None) -> str:
    """The desired state of LPAM's folder `etc_dir` (default: the root's), written to
    `output` when given (refused if it exists); returns its text."""
    text = import_lpam(etc_dir if etc_dir is not None else layout.libpanda)
    if output is None:
        return text

    if output.exists():
        raise ConfigError("already exists; lpam will not overwrite it", path=output,
                          hint="choose another -o FILE or move the existing file away")
    write_atomic(output, text)
    return text
