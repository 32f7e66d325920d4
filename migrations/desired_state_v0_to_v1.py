"""Desired state 0.0 → 1: LPAM's `app-manifest.yaml` becomes lpam's desired state.

Why a "version 0.0" desired state exists at all: LPAM (the bash tool lpam replaces) wrote
`/etc/libpanda.d/app-manifest.yaml` from 2023-08-17 on, and that file already said what
the vehicle should have — which repositories at which branch, which app is current:

```yaml
version: 0.0
repositories:
  jmscslgroup/libpanda-default-apps: {branch: main}
current: pandarecord          # or the string None
```

Treating it as the oldest desired-state version lets an operator point lpam at the old
manifest and lets `lpam import-lpam` reuse this one conversion. Version 1 lists
repositories (order kept) instead of mapping them, calls a branch a `ref`, and names the
app under `app:` (`null` for none):

```yaml
version: 1
repositories:
  - {repo: jmscslgroup/libpanda-default-apps, ref: main}
app: pandarecord
```

LPAM quirks carried over on purpose: `current: None` (a string) meant "no app"; LPAM's own
migration wrote `branch: "null"` when a repository had no branch, and an empty `current`
when no app file existed — both mean "nothing", so they become no ref and no app. A bare
string value (`owner/repo: main`) is read as the branch.

Names are checked here, not only later by the schema, because this is the last place the
position in the old document is known: after the step, a repository is a list item and
the user could not be told which line of their manifest is wrong.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from migrations.step import MigrationError
from schemas.names import check_app_name, check_owner_repo, check_ref

KEYS = ("version", "repositories", "current")
_NOTHING = ("", "null", "None")


def upgrade(doc: dict[str, Any]) -> dict[str, Any]:
    """Return the version-1 equivalent of an LPAM 0.0 manifest; `doc` is left untouched."""
    for key in doc:
        if key not in KEYS:
            raise MigrationError(
                f"unknown key {key!r} in an LPAM 0.0 manifest",
                loc=(key,),
                hint="an LPAM manifest has only version, repositories and current; "
                "remove this key or write a version 1 desired state",
            )
    return {
        "version": 1,
        "repositories": _repositories(doc.get("repositories")),
        "app": _app(doc.get("current")),
    }


def _repositories(value: Any) -> list[dict[str, str]]:
    if value is None:
        return []
    if not isinstance(value, dict):
        raise MigrationError(
            "`repositories` must be a map of owner/repo: {branch: …}",
            loc=("repositories",),
            hint="write e.g. `repositories: {jmscslgroup/libpanda-default-apps: {branch: main}}`",
        )
    out: list[dict[str, str]] = []
    for name, entry in value.items():
        loc: tuple[str | int, ...] = ("repositories", name)
        repo = _checked(check_owner_repo, name, loc, what="repository name")
        spec = {"repo": repo}
        ref = _branch(entry, loc)
        if ref is not None:
            spec["ref"] = ref
        out.append(spec)
    return out


def _branch(entry: Any, loc: tuple[str | int, ...]) -> str | None:
    if isinstance(entry, dict):
        for key in entry:
            if key != "branch":
                raise MigrationError(
                    f"unknown key {key!r} for a repository; LPAM knew only `branch`",
                    loc=(*loc, key),
                    hint="remove it, or write a version 1 desired state with `ref:`",
                )
        loc = (*loc, "branch")
        entry = entry.get("branch")
    if entry is None:
        return None
    if isinstance(entry, int) and not isinstance(entry, bool):
        entry = str(entry)
    if not isinstance(entry, str):
        raise MigrationError(
            "a branch must be a string", loc=loc, hint="quote the branch name: branch: \"…\""
        )
    entry = entry.strip()
    if entry in _NOTHING:
        return None
    return _checked(check_ref, entry, loc, what="branch")


def _app(value: Any) -> str | None:
    if value is None:
        return None
    if not isinstance(value, str):
        raise MigrationError(
            "`current` must be an app name or None",
            loc=("current",),
            hint="write `current: None` for no app, or quote the app name",
        )
    value = value.strip()
    if value in _NOTHING:
        return None
    return _checked(check_app_name, value, ("current",), what="app name")


def _checked(
    check: Callable[[str], str], value: Any, loc: tuple[str | int, ...], *, what: str
) -> str:
    """Run a `schemas.names` check, turning its ValueError into a located MigrationError."""
    if not isinstance(value, str):
        raise MigrationError(f"{what} must be a string, not {value!r}", loc=loc)
    try:
        return check(value)
    except ValueError as exc:
        raise MigrationError(f"{value!r} is not a valid {what}", loc=loc, hint=str(exc)) from None
