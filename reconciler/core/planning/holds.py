"""Holds: what keeps the car as it is while the desired state stays what it was.

An operator's stop (`lpam stop`) and a rollback (`lpam rollback`) hold against the desired
state last applied — its content, not its formatting (`fingerprint`), whichever file or
revision of the followed repository it came from. A stop holds one app until `lpam
start`; both end when that desired state changes (`released`, `hold_reason`), or with
`lpam apply --release`. Pure: the state record and the desired state in, values out.
"""

from __future__ import annotations

import hashlib
import json
import shlex
from collections.abc import Sequence
from pathlib import PurePosixPath

from schemas.desired import DesiredState
from schemas.record import AppRecord, DesiredRef, HistoryEntry, StateRecord


def fingerprint(desired: DesiredState | None) -> str:
    """A desired state's content, written in the oldest version of the document that can
    say it: version 1 for at most one app, version 2 for more. One form, so that a hold
    recorded by any lpam since version 1 (an operator's stop, a rollback) ends only
    because the desired state changed, never because lpam was upgraded. A `rollout:`
    says which cars take a revision first, not what runs: it is left out, so a hold
    outlives an edit of the waves (and fingerprints from before rollouts stay)."""
    if desired is None:
        text = ""
    elif len(desired.apps) > 1:
        text = desired.model_dump_json(exclude={"rollout"})
    else:
        dumped = desired.model_dump(mode="json", exclude={"rollout"})
        shaped = {("app" if k == "apps" else k): (v[0] if v else None) if k == "apps" else v
                  for k, v in dumped.items()}
        shaped["version"] = 1
        text = json.dumps(shaped, ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def desired_ref(desired: DesiredState, source: str) -> DesiredRef:
    """What an apply records it works toward: holds are held against its content."""
    return DesiredRef(fingerprint=fingerprint(desired), source=source)


def release_command(record: StateRecord) -> str:
    """The command that ends the holds: an apply, with `--release`, of the desired state
    they hold against. One applied from a file names that file (recorded absolute): alone,
    `lpam apply --release` applies the default file — another desired state, or none. A
    revision of the followed repository (`<repository>@<revision>/<file>`) is what
    `--release` alone applies."""
    source = record.desired.source if record.desired is not None else None
    if source is not None and PurePosixPath(source).is_absolute():
        return f"lpam apply -f {shlex.quote(source)} --release"
    return "lpam apply --release"


def hold_reason(record: StateRecord, desired: DesiredState) -> str | None:
    """Why a rollback holds the car, while the desired state is unchanged (None: no hold)."""
    hold = record.hold
    if hold is None or hold.desired != fingerprint(desired):
        return None
    return (f"held by `lpam rollback` at generation {hold.name}: nothing is proposed "
            f"until the desired state changes (`{release_command(record)}` ends the hold)")


def released(record: StateRecord, desired: DesiredState) -> tuple[StateRecord, list[str]]:
    """An operator's stop holds against the desired state last applied: once that desired
    state changed (a new file, a new revision), the stop is over and the app is planned as
    any stopped app — started. The record as planned, and what is said of each stop."""
    applied = record.desired
    if applied is None or applied.fingerprint == fingerprint(desired):
        return record, []
    notes = []
    for app in record.apps:
        if app.held:
            notes.append(f"the operator's stop of {app.name} ends: the desired state changed "
                         f"since it was last applied (from {applied.source})")
            record = record.with_app(app.name, app.model_copy(
                update={"held": False, "held_by": None}))
    return record, notes


def same_set(entries: Sequence[HistoryEntry], apps: Sequence[AppRecord]) -> bool:
    """Whether a set of the history is what `apps` are: each app's name, generation and
    parameters."""
    def key(name: str, generation: str, params: dict[str, str]) -> tuple[str, ...]:
        return (name, generation, *sorted(f"{k}={v}" for k, v in params.items()))

    return {key(e.app, e.generation, e.params) for e in entries} == \
        {key(a.name, a.generation, a.params) for a in apps}
