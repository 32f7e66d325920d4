"""Repository steps: a checkout of the store at its commit, a repository removed.

Idempotent on their outcome: a checkout already at its commit is left alone.
"""

from __future__ import annotations

from reconciler.base.errors import StoreDamagedError
from reconciler.engine.execution.context import Context
from reconciler.engine.execution.steps.folders import known
from reconciler.engine.records import damage
from schemas.plan import CheckoutStep, RemoveStep
from schemas.record import RepositoryRecord


def checkout(step: CheckoutStep, ctx: Context) -> None:
    check_out(step, ctx)
    record_checkout(step, ctx)


def check_out(step: CheckoutStep, ctx: Context) -> None:
    """The checkout's work on its own repository, which touches nothing another
    repository's checkout does: the executor runs several at once (record_checkout after)."""
    key, url, commit = step.key, step.url, known(step.commit, step.id, "commit")
    try:
        present = ctx.store.has_commit(key, commit)
    except StoreDamagedError as exc:  # since a saved plan was made: the store is a cache
        ctx.log(damage.renew(ctx.store, key, url, exc.damage))
        present = ctx.store.has_commit(key, commit)
    if not present:
        ctx.store.fetch(key, url, want=commit)
    elif ctx.store.origin_url(key) != url:
        # a pinned repository moved to another URL: the commit it needs is here already,
        # so no network (the plan said so: core/planning/diff.py)
        ctx.store.repoint(key, url)
    if ctx.store.head(key) != commit:
        ctx.store.checkout(key, commit)


def record_checkout(step: CheckoutStep, ctx: Context) -> None:
    key, url, commit = step.key, step.url, known(step.commit, step.id, "commit")
    before = ctx.record.repository(key)
    # what ran stays what ran until the apply succeeds (the same URL: the same repository)
    applied = before.applied if before is not None and before.url == url else None
    entry = RepositoryRecord(key=key, url=url, ref=step.ref, commit=commit, applied=applied)
    others = [r for r in ctx.record.repositories if r.key != key]
    ctx.save(ctx.record.model_copy(update={"repositories": sorted([*others, entry],
                                                                  key=lambda r: r.key)}))


def remove(step: RemoveStep, ctx: Context) -> None:
    key = step.key
    if ctx.layout.repository_dir(key).exists():
        ctx.store.remove(key)
    others = [r for r in ctx.record.repositories if r.key != key]
    ctx.save(ctx.record.model_copy(update={"repositories": others}))
