"""What an apply with nothing to run still does: it ends what an earlier apply left owed.

A last apply that was cut off, deferred or interrupted, and a cutover cut off after its
last step, stay in the state record until an apply ends them; status reads them there and
says "`lpam apply` goes on from where it stood". When the machine reached the desired
state by another way since (`lpam start` ran what was left), or holds keep it from the
rest (`lpam stop` after the cut), such an apply has no step left, and only writes the
record. The plan says so (`settling`) and apply does it (engine/execution/recovery.py
`settled`), from this one decision: a status that owes and a plan that says "No changes"
never meet (the consistency property, tests/reliability/test_consistency.py).
"""

from __future__ import annotations

from schemas.plan import Action, Change, Plan
from schemas.record import StateRecord

STALE: frozenset[str] = frozenset({"in progress", "deferred", "interrupted"})
"""Last applies that owe the car something (to resume, or to try again): an apply that
finds nothing to do ends them. Under the apply lock an `in progress` is one cut off."""

ADDRESS = "last-apply"
HELD = "No changes because of the holds in force: "  # core/planning/plan.py held_summary


def owed(record: StateRecord) -> str | None:
    """What an earlier apply left owed, in the record's words (None: nothing). Read under
    the apply lock: an apply still `in progress` there was cut off."""
    last = record.last_apply
    if last is not None and last.result in STALE:
        if last.result == "in progress":
            return f"the last apply (cut off, began {last.time})"
        return f"the last apply ({last.result} at {last.time})"
    if record.cutover is not None and record.cutover.rollback is None:
        return f"the cutover cut off (began {record.cutover.began})"
    return None


def settling(plan: Plan, record: StateRecord) -> Plan:
    """`plan`, which has no step, as the change it still makes: ending what an earlier
    apply left owed (`owed`), with a summary that says why nothing runs — the holds in
    force, or a machine that matches. Unchanged when there is a step or nothing is owed.
    The seal covers the steps, not the words (schemas/plan.py): it stays as it was."""
    what = owed(record)
    if plan.steps or what is None or any(c.address == "rollback" for c in plan.changes):
        return plan
    change = Change(address=ADDRESS, action=Action.UPDATE,
                    reason=f"{what} has nothing left to run: an apply records it finished")
    holds = plan.summary.removeprefix(HELD)
    why = f" because of the holds in force: {holds.rstrip('.')}" if holds != plan.summary \
        else ": the machine matches the desired state"
    return plan.model_copy(update={
        "changes": [*plan.changes, change],
        "summary": f"Nothing to run{why}; `lpam apply` records that {what} has "
                   "nothing left to do.",
    })
