"""`lpam status`: the status report (schemas/report.py), read (reconciler/report/gather.py),
built (reconciler/report/build.py) and rendered as the table (reconciler/report/table.py)
or as `--json`: the report itself, with `app`, the first installed app, for the readers
from before several apps.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from reconciler.base.layout import Layout
from reconciler.report import table
from reconciler.report.build import build
from reconciler.report.gather import Objects, gather

if TYPE_CHECKING:
    from reconciler.base.unit import UnitState
    from schemas.plan import Plan
    from schemas.record import StateRecord
    from schemas.report import CatalogRow, StatusReport

FIRST_ONLY_NEW = {"claims", "claims_known", "said", "standing", "rollback_hold"}
"""What `app` never had: it keeps the shape readers from before several apps knew."""


def report(layout: Layout, *, store: Objects | None = None,
           state: Callable[[str], UnitState] | None = None, manager: str | None = None,
           record: StateRecord | None = None, plan: Plan | str | None = None,
           gates: str | None = None, listed: bool = True) -> StatusReport:
    """The car now. `state` asks the service manager (`manager`) about a unit; `plan`
    and `gates`, where a face shows them, say what an apply would do and the gates now;
    `listed` False leaves out the rows of the repositories' apps (no catalog is read)."""
    return build(gather(layout, store=store, state=state, manager=manager, record=record,
                        listed=listed), plan=plan, gates=gates)


def json_of(shown: StatusReport) -> dict[str, Any]:
    """`--json`: the report, and `app` (the first installed app) as readers before several
    apps read it."""
    body = shown.model_dump(mode="json")
    first = shown.app
    app = None if first is None else first.model_dump(mode="json", exclude=FIRST_ONLY_NEW)
    return {"app": app, **body}


def as_json(layout: Layout, *, store: Objects | None = None,
            state: Callable[[str], UnitState] | None = None,
            manager: str | None = None) -> dict[str, Any]:
    return json_of(report(layout, store=store, state=state, manager=manager))


def as_table(layout: Layout, *, store: Objects | None = None,
             state: Callable[[str], UnitState] | None = None,
             manager: str | None = None) -> str:
    return table.render(report(layout, store=store, state=state, manager=manager))


def rows(layout: Layout, *, record: StateRecord | None = None,
         store: Objects | None = None) -> list[CatalogRow]:
    """Every app of every recorded repository at its recorded commit, and each installed
    app even when no catalog lists it any more."""
    return report(layout, store=store, record=record).apps
