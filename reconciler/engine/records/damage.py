"""The repository store is a cache of the remotes: what is done with a damaged copy.

Place in the flow: `engine/observe/targets.py` checks each repository's copy before plan or apply
reads it, and the checkout step of a saved plan meets damage when it reads one; both come
here (so it sits below both the engine and the probes). Apply fetches the repository anew
(`Store.renew`: network first, the damaged copy kept aside) and goes on; a plan, which
must change nothing, refuses the copy and says what the next apply does. No network means
no change at all: the running app and the damaged copy stay as they were, and the error
says so.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from reconciler.base.errors import GitError, StoreDamagedError
from schemas.names import redact

if TYPE_CHECKING:
    from reconciler.engine.execution.ports import Store


def renew(store: Store, key: str, url: str, damage: str) -> str:
    """Fetch `key` anew from `url` in place of its damaged copy; the sentence that tells
    the user so. StoreDamagedError when the fetch fails (nothing moved)."""
    try:
        aside = store.renew(key, url)
    except GitError as exc:
        raise StoreDamagedError(
            key, damage, after=f"; fetching it anew failed: {exc.message}",
            hint="nothing was changed and the running app is untouched; the next `lpam "
            "apply` with network fetches it anew") from None
    return (f"repository {key}: its copy in the store was damaged ({damage}); fetched anew "
            f"from {redact(url)}, the damaged copy kept at {aside}")


def refused(key: str, url: str, damage: str, path: Path | None) -> StoreDamagedError:
    """The error of a plan that meets a damaged copy: it names the repository, the damage
    and the copy's place (`path`), and what the next apply will do."""
    return StoreDamagedError(
        key, damage, path=path,
        hint=f"the store is a cache: the next `lpam apply` moves the damaged copy aside and "
        f"fetches it anew from {redact(url)}; nothing was changed")
