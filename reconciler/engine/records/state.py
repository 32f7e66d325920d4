"""Read and write the state record (`var/lib/lpam/state.json`, format in schemas/record.py).

Every write is atomic and bumps the serial; the first write fixes the lineage. A record
written by a newer lpam is refused by name instead of being misread.

Reading also *settles* the record: when the app's status says a script was under way
(`starting`, run `r1`) and that run's exit file (written by the script's guard, see
adapters/scripts.py) says it ended with 0, the script finished after lpam died — the
record reads as if lpam had seen it (`running`), so the script is never run twice. A run
with no exit file, or a failing one, leaves the status as it is: the step runs again.

A missing record on a machine that has generations on disk means the record was lost or
moved aside: each generation becomes a *stray* (schemas/record.py), so that the next apply
stops and uninstalls it with its own scripts before installing anything. A damaged record
is refused, and the hint says how to get to that safe path.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Optional, TypeVar

from reconciler.base.atomic import write_atomic
from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.base.reading import MIB, read_bounded
from reconciler.engine.records.generations import installed_on_disk
from schemas.kinds import DocumentKind
from schemas.record import AppRecord, StateRecord, Stray

if TYPE_CHECKING:
    from pydantic import BaseModel

    from schemas.agent import AgentStatus
    from schemas.override import LocalOverride

# Imported inside functions: legacy.appdir (~25 modules) loads only when no record exists; the
# other schemas and readers add 1-2 modules each once this module is loaded (small gain).

LIMIT = 4 * MIB

DAMAGED_HINT = (
    "move it aside (`mv {path} {path}.damaged`): the next `lpam apply` then stops and "
    "uninstalls every app it finds installed under {generations} before it installs the "
    "desired one"
)

ExitCode = Callable[[str], Optional[int]]
_M = TypeVar("_M", bound="BaseModel")

SETTLED = {"installing": "installed", "starting": "running", "stopping": "installed"}


def read_override(layout: Layout) -> LocalOverride | None:
    """The local override in force (`override.json`); None when the car follows its fleet
    file (or follows none)."""
    from schemas.override import LocalOverride

    return _read_optional(layout.override, DocumentKind.OVERRIDE, LocalOverride,
                          "move the file aside: the car then follows its fleet file again")


def read_agent_status(layout: Layout) -> AgentStatus | None:
    """What the agent's passes recorded (`status.json`); None where no agent ever ran."""
    from schemas.agent import AgentStatus

    return _read_optional(layout.agent_status, DocumentKind.AGENT_STATUS, AgentStatus,
                          "move the file aside; the next pass writes a new one")


def _read_optional(path: Path, kind: DocumentKind, model: type[_M], hint: str) -> _M | None:
    from reconciler.base.loading import read_text
    from reconciler.core.written import parse_json

    if not path.exists():
        return None
    return parse_json(kind, read_text(path), path, model, hint=hint)


def read_record(layout: Layout) -> StateRecord:
    """The last recorded state, settled; on a machine with no record, the strays on disk."""
    from reconciler.core.written import parse_json

    path = layout.state_record
    hint = DAMAGED_HINT.format(path=path, generations=layout.generations)
    try:
        data = read_bounded(path, limit=LIMIT, follow_symlinks=False, what="state record",
                            hint=hint)
    except FileNotFoundError:
        return StateRecord(strays=found_installed(layout))
    try:
        record = parse_json(DocumentKind.STATE_RECORD, data.decode("utf-8"), path, StateRecord,
                            hint=hint)
    except UnicodeDecodeError as exc:
        raise ConfigError(f"the state record is not UTF-8 text (byte {exc.start})",
                          path=path, hint=hint) from None
    except RecursionError:
        raise ConfigError("the state record is nested too deeply to be one lpam wrote",
                          path=path, hint=hint) from None
    return settle(record, exit_code=lambda run: run_result(layout, run))


def found_installed(layout: Layout) -> list[Stray]:
    """Apps installed on this machine that no record of lpam's knows: generations on disk
    (the record was lost), and the app LPAM installed on a vehicle that used it. Each may
    hold the CAN hardware, so each is stopped and uninstalled before any app is installed."""
    from reconciler.engine.records.legacy.appdir import lpam_current

    strays = [Stray(name=g.name, generation=g.generation, params=g.params,
                    service=g.service if g.scriptless else None)
              for g in installed_on_disk(layout)]
    legacy = lpam_current(layout)
    if legacy is not None:
        strays.append(Stray(name=legacy, generation=LPAM_GENERATION, folder=legacy))
    return strays


LPAM_GENERATION = "lpam"  # what `lpam status` and plans call an app LPAM installed


def settle(record: StateRecord, *, exit_code: ExitCode) -> StateRecord:
    """The record as it stands once the script runs it was waiting for are accounted for."""
    strays = []
    for stray in record.strays:
        finished = stray.run is not None and exit_code(stray.run) == 0
        if finished and stray.pending == "uninstall":
            continue
        if finished:
            stray = stray.model_copy(update={"stopped": True, "pending": None, "run": None})
        strays.append(stray)
    record = record.model_copy(update={"strays": strays})
    for app in record.apps:
        if app.run is None or exit_code(app.run) != 0:
            continue
        settled: AppRecord | None = None if app.status == "uninstalling" else \
            app.model_copy(update={"status": SETTLED.get(app.status, app.status), "run": None})
        record = record.with_app(app.name, settled)
    return record


def run_result(layout: Layout, run: str) -> int | None:
    """The exit code a script's guard wrote for `run`, or None if it never finished."""
    try:
        text = read_bounded(layout.run_result(run), limit=64, follow_symlinks=False).decode()
        return int(text.strip())
    except (FileNotFoundError, ConfigError, UnicodeDecodeError, ValueError):
        return None


def write_record(layout: Layout, record: StateRecord) -> StateRecord:
    """Persist `record` as the next serial; returns what was written."""
    lineage = record.lineage or str(uuid.uuid4())
    written = record.model_copy(update={"lineage": lineage, "serial": record.serial + 1})
    text = json.dumps(written.model_dump(mode="json"), indent=2, sort_keys=True) + "\n"
    write_atomic(layout.state_record, text)
    return written

