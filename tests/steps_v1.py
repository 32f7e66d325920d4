"""Steps written as version 1 wrote them (`args`: a mapping of strings), for the tests
that drive one runner at a time: carried into the typed step by the plan's migration,
as a saved version-1 plan is."""

from __future__ import annotations

from typing import Optional, Union

from pydantic import TypeAdapter

from migrations.plan_v1_to_v2 import typed_step
from schemas.plan import Phase, Step, StepKind

ArgValue = Optional[Union[str, list[str], dict[str, str]]]

_STEP: TypeAdapter[Step] = TypeAdapter(Step)  # type: ignore[arg-type, unused-ignore]


def step(kind: StepKind, phase: Phase, target: str, **args: ArgValue) -> Step:
    item: dict[str, object] = {"id": f"{kind.value}:{target}", "kind": kind.value,
                               "phase": phase.value, "args": args, "needs": []}
    return _STEP.validate_python(typed_step(item, 0))
