"""The one exception tree of lpam.

Every error a user can cause or meet is an `LpamError`; the CLI is the only place that
renders them (one line, plus a hint saying what to do) and turns them into exit codes.
Anything else that escapes is a bug: the CLI writes its traceback to the debug log.
"""

from __future__ import annotations

from pathlib import Path

# shorten: re-exported, where adapters and vehicle/ have always imported it from
from reconciler.base.text import printable
from reconciler.base.text import shorten as shorten

DETAIL_LINES = 20


class Terminated(BaseException):
    """SIGTERM, raised where lpam stands (like KeyboardInterrupt for Ctrl-C), so that the
    running script is stopped first and the apply records that it was interrupted."""


class LpamError(Exception):
    """Base of every error lpam reports to a user. Its message is one line of bounded
    length, whatever value it echoes."""

    exit_code = 1
    word = "error"  # what the CLI's line begins with: what kind of ending this is

    def __init__(self, message: str, *, hint: str | None = None,
                 details: list[str] | None = None) -> None:
        # one line: a server's or a library's text may end in a line break, which a
        # terminal-safe rendering would show as a stray "?" ("remote side.?")
        message = shorten(" ".join(message.strip().splitlines()))
        super().__init__(message)
        self.message = message
        self.hint = hint
        self.details = [shorten(line, 200) for line in (details or [])[-DETAIL_LINES:]]

    def render(self) -> str:
        """The text the CLI prints: the message, any details (such as the last lines of a
        failed app's output) indented below it, then the hint on its own line."""
        text = f"{self.word}: {self.message}"
        for line in self.details:
            text += f"\n  | {printable(line)}"
        if self.hint:
            text += f"\n  hint: {self.hint}"
        return text


def place(path: Path, line: int | None, column: int | None) -> str:
    """`file:line:col` as editors and compilers write it (what they know of it)."""
    where = str(path)
    if line is not None:
        where += f":{line}"
        if column is not None:
            where += f":{column}"
    return where


class ConfigError(LpamError):
    """A document (desired state, catalog, plan, legacy file) is at fault.

    Carries the file, line and column (1-based) so the user can go straight to the spot.
    """

    def __init__(
        self,
        message: str,
        *,
        path: Path | str | None,
        line: int | None = None,
        column: int | None = None,
        hint: str | None = None,
    ) -> None:
        super().__init__(message, hint=hint)
        self.path = Path(path) if path is not None else None
        self.line = line
        self.column = column

    @property
    def where(self) -> str:
        return "<input>" if self.path is None else place(self.path, self.line, self.column)

    def render(self) -> str:
        text = f"error: {self.where}: {self.message}"
        if self.hint:
            text += f"\n  hint: {self.hint}"
        return text


class VersionError(ConfigError):
    """A document written by a newer lpam than this one (or of an unknown version)."""


class GitError(LpamError):
    """Talking to a git repository failed: unreachable server, bad URL, corrupt store."""


class StoreDamagedError(GitError):
    """A repository's copy in the store is damaged: a truncated or overwritten pack, a lost
    pack index, refs naming objects that are gone (what a power cut or a failing SD card
    leaves). The store is a cache of the remotes, so nothing reads a damaged copy: status
    notes it, plan refuses it, and apply fetches the repository anew, keeping the damaged
    copy aside."""

    def __init__(self, key: str, damage: str, *, path: Path | None = None,
                 hint: str | None = None, after: str = "") -> None:
        where = f" ({path})" if path is not None else ""
        super().__init__(
            f"repository {key}: its copy in the store is damaged: {damage}{where}{after}",
            hint=hint or "the store is a cache: the next `lpam apply` moves the damaged copy "
            "aside and fetches the repository anew; nothing was changed")
        self.key = key
        self.damage = damage


class PushRefusedError(GitError):
    """The repository does not accept a push from this machine: read-only (a mirror, git
    daemon without receive-pack), no write access (a read-only token or deploy key), or a
    protected branch. Unlike a network failure, asking again soon cannot help."""


class RefNotFoundError(GitError):
    """The requested branch, tag or commit does not exist in the repository."""


class LocalEditsError(GitError):
    """A checkout in the store has edits that a checkout would throw away."""


class CatalogError(LpamError):
    """The desired app is not in, or ambiguous across, the app catalogs."""


class PlanError(LpamError):
    """A plan cannot be built (cycle in the step graph) or used (stale, tampered)."""


class StalePlanError(PlanError):
    """The saved plan was made against a state record that has since changed."""


class LockError(LpamError):
    """Another apply holds the lock and did not release it in time."""


class StepError(LpamError):
    """A step of an apply failed; the journal says how far the apply got."""


class StateWriteError(ConfigError):
    """The state record could not be written (a full disk, a read-only filesystem). The
    step whose intent it was did no work, so the record on disk is still exact;
    `explained` once the message says what it shows (engine/execution/recovery.py)."""

    explained = False


class ServiceError(LpamError):
    """The service manager (systemd, supervisord) refused or failed an operation on a unit,
    or could not be reached or started."""


class DependencyError(StepError):
    """An app's apt packages, pip requirements or ROS workspace could not be prepared.
    Raised before the cutover: the running app is untouched."""


class TrustError(LpamError):
    """A commit the vehicle would apply is not signed by a key it trusts."""


class StopRequested(LpamError):
    """A stop was asked for (the agent's SIGTERM) and the apply stopped at a step boundary
    before its cutover: nothing is half done, and the next pass resumes from the journal."""

    exit_code = 143


class HealthError(StepError):
    """The started app did not stay healthy; the apply rolls back to the previous app."""

    exit_code = 3


class VehicleSourceError(LpamError):
    """The vehicle's signal source (a CAN bus, a recording followed as it grows, a log)
    cannot be opened or read: a missing file, an unknown python-can interface, a bus that
    does not answer. At a gate this counts as "no signal", never as a traceback."""


class Deferred(LpamError):
    """A gate was closed when the cutover was due (the vehicle moving, a lock held, outside
    a window). Not a failure: everything was prepared, the running app is untouched, and the
    next pass tries again. 75 is EX_TEMPFAIL of sysexits(3). Said as `deferred:`, never
    `error:`: the README tells the user a deferral is not a failure. `gates`: the names of
    the gates that were closed (vehicle, window, lock), which the state record keeps."""

    exit_code = 75
    word = "deferred"

    def __init__(self, message: str, *, hint: str | None = None,
                 gates: tuple[str, ...] = ()) -> None:
        super().__init__(message, hint=hint)
        self.gates = gates
