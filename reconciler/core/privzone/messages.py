"""What the phone asks for and what it is told: Privzone's requests, commands and statuses.

A completed message from the phone (`framing.Inbox`) becomes one typed request here, or a
`ProtocolError` whose `text` is the one status the phone shows. Every value that later
names a repository, a branch, an app or an environment variable is checked *here*, by the
rules the desired state applies to the same values (schemas/names.py, schemas/desired.py):
bluezone pasted these values into shell command lines, which is how a phone could run
anything on the car (lpam-legacy.md).

The status texts the phone reacts to are fixed by the phone: it asks again for the app list
(command `A`) on exactly "App command success!", "Repository updated!" and "Repository
removed!", and shows every other text as it is. lpam keeps bluezone's texts and, on a
failure, says why after a colon: "Error adding repository: …".
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Callable, Final, Union

from pydantic import ValidationError

from reconciler.base.errors import LpamError
from reconciler.base.text import printable, shorten
from reconciler.core.privzone.framing import encode_message, utf16_length
from reconciler.core.privzone.temperature import Unit, parse_unit, temperature_text, unit_value
from schemas.desired import AppSpec
from schemas.enums import StrEnum
from schemas.names import check_app_name, check_owner_repo, check_ref
from schemas.operator import OperatorAction
from schemas.report import CatalogRow

__all__ = [
    "AddRepository", "AppEnable", "AppParams", "AppUpdate", "Command", "Failure",
    "InputKind", "NotServed", "ProtocolError", "ReadSummary", "RemoveRepository", "Request",
    "Status", "Unit", "app_info_message", "parse_command", "parse_input", "parse_unit",
    "summary_message", "temperature_text", "unit_value",
]

SHOWN = 60  # characters of a phone's value echoed in a status


class ProtocolError(LpamError):
    """A message or command the phone sent that lpam does not act on; `text` is the status
    the phone is told (one line, bounded)."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = self.message


class InputKind(StrEnum):
    """The `type` of a message on the input characteristic."""

    APP_ENABLE = "app_enable"
    APP_UPDATE = "app_update"
    ADD_REPOSITORY = "app_add_repository"
    REMOVE_REPOSITORY = "app_remove_repository"
    APP_PARAMS = "app_params"  # lpam's: the app's parameters (the paper's future work)
    SUMMARY = "app_summary"  # lpam's: plan summary, applied revision, update gates
    WIFI_ADD = "wifi_add"  # bluezone's privacy and network features: not lpam's to serve
    WIFI_REMOVE = "wifi_remove"
    ZONEFILE = "zonefile"


NOT_SERVED_KINDS: Final = frozenset({InputKind.WIFI_ADD, InputKind.WIFI_REMOVE,
                                     InputKind.ZONEFILE})


@dataclass(frozen=True)
class AppEnable:
    """Make `app` the installed app; None (the phone's "None") uninstalls the current one."""

    app: str | None


@dataclass(frozen=True)
class AppUpdate:
    """Follow every repository's branch to its newest commit."""


@dataclass(frozen=True)
class AddRepository:
    """Add a GitHub repository `owner/name`, at `branch` (None: its default branch)."""

    repository: str
    branch: str | None


@dataclass(frozen=True)
class RemoveRepository:
    """Remove a repository, named as the app list names it."""

    repository: str


@dataclass(frozen=True)
class AppParams:
    """Set the parameters (environment variables of its scripts) of `app`."""

    app: str
    params: dict[str, str]


@dataclass(frozen=True)
class ReadSummary:
    """Send the summary: what a plan would do, the revision applied, the update gates."""


@dataclass(frozen=True)
class NotServed:
    """A request of bluezone's that lpam does not serve (WiFi, zone files). It carries no
    contents: a WiFi request holds a password, which must not reach a log."""

    kind: str


Request = Union[AppEnable, AppUpdate, AddRepository, RemoveRepository, AppParams, ReadSummary,
                NotServed]


class Failure(StrEnum):
    """What failed, in bluezone's words; the phone is told `Failure.X.because(reason)`
    ("Error stopping app: stop.sh exited 1"). bluezone's "Error enabling app X" names the
    app: `Status.enabling_failed`."""

    ENABLING = "Error enabling app"
    STOPPING = "Error stopping app"
    RESTARTING = "Error restarting app"
    UPDATING = "Error updating app"
    ADDING = "Error adding repository"
    REMOVING = "Error removing repository"
    PARAMS = "Error setting app parameters"
    SUMMARY = "Error reading summary"

    def because(self, reason: str) -> str:
        return f"{self.value}: {reason}"


class Status:
    """The texts of the status characteristic (a namespace, never instantiated)."""

    HELLO: Final = "Hello from the Pi!"
    APP_COMMAND_SUCCESS: Final = "App command success!"
    REPOSITORY_UPDATED: Final = "Repository updated!"
    REPOSITORY_REMOVED: Final = "Repository removed!"
    APP_UPDATED: Final = "App updated!"
    # the phone sends `A` again, to show the new app list, on exactly these
    REFRESHING: Final = frozenset({APP_COMMAND_SUCCESS, REPOSITORY_UPDATED,
                                   REPOSITORY_REMOVED})

    @staticmethod
    def enabling_failed(app: str | None, reason: str) -> str:
        """bluezone's "Error enabling app X", with the reason; None is the phone's "None"."""
        return f"{Failure.ENABLING} {'None' if app is None else shown(app)}: {reason}"

    @staticmethod
    def not_served(what: str) -> str:
        """For `NotServed` and `Command.NOT_SERVED`: lpam manages apps, nothing else."""
        return (f"Not served: {shown(what)} is not an app request; lpam serves the app part "
                "of Privzone only")


def shown(value: str) -> str:
    """A value from the phone as a status may echo it: one line, at most `SHOWN` chars."""
    return printable(shorten(value, SHOWN))


# --- the envelope -----------------------------------------------------------------------

def parse_input(body: bytes) -> Request:
    """The request a completed input message makes, or ProtocolError with the phone's text.

    Checked in bluezone's order: UTF-8 and JSON, the keys `type`, `length`, `contents`, the
    length (JavaScript's, in UTF-16 units; bluezone compared Python's `len`, and then went
    on regardless), then the type; then the contents, by the type's own rules.
    """
    envelope = _envelope(body)
    kind = envelope["type"]
    if kind in NOT_SERVED_KINDS:
        return NotServed(kind)
    parser = _PARSERS.get(kind)
    if parser is None:
        raise ProtocolError(f"Unregognized type: {shown(kind)}")  # sic: the phone's text
    return parser(envelope["contents"])


def _envelope(body: bytes) -> dict[str, str]:
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ProtocolError(f"File format error! Not UTF-8 text (byte {error.start})") from None
    document = _json(text, "File format error! Not JSON")
    if not isinstance(document, dict):
        raise ProtocolError("File format error! Not a JSON object")
    for key in ("type", "length", "contents"):
        if key not in document:
            raise ProtocolError(f"Key error, missing '{key}' in JSON!")
    kind, length, contents = document["type"], document["length"], document["contents"]
    if not isinstance(kind, str):
        raise ProtocolError("Key error, 'type' must be a string")
    if not isinstance(length, int) or isinstance(length, bool):
        raise ProtocolError("Key error, 'length' must be a whole number")
    if not isinstance(contents, str):
        raise ProtocolError("Key error, 'contents' must be a string of JSON")
    received = utf16_length(contents)
    if received != length:
        raise ProtocolError(f"Upload issue, length mismatch! ({length} announced, "
                            f"{received} received)")
    return {"type": kind, "contents": contents}


def _json(text: str, failure: str) -> object:
    """`text` parsed; a failure says where. Nesting too deep for the parser is a fault of
    the message, not of lpam (64 KiB of `[` would otherwise raise RecursionError)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise ProtocolError(f"{failure}: {error.msg} at character {error.pos}") from None
    except RecursionError:
        raise ProtocolError(f"{failure}: nested too deeply") from None
    except ValueError as error:  # e.g. an integer past int_max_str_digits
        raise ProtocolError(f"{failure}: {shorten(str(error), SHOWN)}") from None


# --- the contents, type by type ---------------------------------------------------------

Fields = dict[str, object]


def _fields(contents: str, failed: Callable[[str], str], known: Sequence[str]) -> Fields:
    value = _json(contents, failed("'contents' is not JSON"))
    if not isinstance(value, dict):
        raise ProtocolError(failed("'contents' is not a JSON object"))
    for key in value:
        if key not in known:
            raise ProtocolError(failed(f"unknown field {shown(key)!r}"))
    return value


def _text(fields: Fields, key: str, failed: Callable[[str], str]) -> str:
    value = fields.get(key)
    if value is None:
        raise ProtocolError(failed(f"missing '{key}'"))
    if not isinstance(value, str):
        raise ProtocolError(failed(f"'{key}' must be a string"))
    return value


def _checked(value: str, key: str, check: Callable[[str], str],
             failed: Callable[[str], str]) -> str:
    try:
        return check(value)
    except ValueError as error:
        raise ProtocolError(failed(f"{key} {shown(value)!r}: {error}")) from None


def _app_enable(contents: str) -> AppEnable:
    fields = _fields(contents, Failure.ENABLING.because, ("app",))
    app = _text(fields, "app", Failure.ENABLING.because)
    if app == "None":  # the phone's last choice in its list: no app
        return AppEnable(None)
    return AppEnable(_checked(app, "app", check_app_name, Failure.ENABLING.because))


def _app_update(contents: str) -> AppUpdate:
    """The contents are not read: bluezone ignored them, and what a phone sends with an
    update (`{}`, `""`) differs between its versions."""
    return AppUpdate()


def _add_repository(contents: str) -> AddRepository:
    failed = Failure.ADDING.because
    fields = _fields(contents, failed, ("repository", "branch"))
    repository = _checked(_text(fields, "repository", failed), "repository",
                          check_owner_repo, failed)
    branch: str | None = None
    if fields.get("branch") not in (None, ""):  # the phone's empty field: the default branch
        branch = _checked(_text(fields, "branch", failed), "branch", check_ref, failed)
    return AddRepository(repository, branch)


def _repository_name(value: str) -> str:
    """A name the app list shows: `owner/name`, or a repository's own `name:` (the desired
    state's rule for `name:`, which a repository given by URL may carry)."""
    return check_owner_repo(value) if "/" in value else check_app_name(value)


def _remove_repository(contents: str) -> RemoveRepository:
    failed = Failure.REMOVING.because
    fields = _fields(contents, failed, ("repository",))
    return RemoveRepository(_checked(_text(fields, "repository", failed), "repository",
                                     _repository_name, failed))


def _app_params(contents: str) -> AppParams:
    failed = Failure.PARAMS.because
    fields = _fields(contents, failed, ("app", "params"))
    app = _checked(_text(fields, "app", failed), "app", check_app_name, failed)
    if app == "None":
        raise ProtocolError(failed("'app' must name an app, not None"))
    params = fields.get("params")
    if not isinstance(params, dict):
        raise ProtocolError(failed("'params' must be an object of names to strings"))
    for key, value in params.items():
        if not isinstance(value, str):
            raise ProtocolError(failed(f"params.{shown(key)} must be a string"))
    try:  # the desired state's own rules for parameters, so that both always agree
        AppSpec.model_validate({"name": app, "params": params})
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        message = str(first["msg"]).replace("Value error, ", "", 1)
        raise ProtocolError(failed(f"{shown(where)}: {message}")) from None
    return AppParams(app, dict(params))


def _summary(contents: str) -> ReadSummary:
    return ReadSummary()


_PARSERS: Mapping[str, Callable[[str], Request]] = {
    InputKind.APP_ENABLE: _app_enable,
    InputKind.APP_UPDATE: _app_update,
    InputKind.ADD_REPOSITORY: _add_repository,
    InputKind.REMOVE_REPOSITORY: _remove_repository,
    InputKind.APP_PARAMS: _app_params,
    InputKind.SUMMARY: _summary,
}


# --- commands ---------------------------------------------------------------------------

class Command(StrEnum):
    """What a write to the command characteristic asks for."""

    INFO = "A"  # send the app list
    STOP = "As"
    RESTART = "Ar"  # bluezone: stop, then start
    NOT_SERVED = "not served"  # bluezone's R, P (zone files), W, S (WiFi)

    @property
    def action(self) -> OperatorAction | None:
        """The operator action a command is, for the workflow's start/stop/restart."""
        return {"As": OperatorAction.STOP, "Ar": OperatorAction.RESTART}.get(self.value)


_COMMANDS: Final = {"A": Command.INFO, "As": Command.STOP, "Ar": Command.RESTART,
                    "R": Command.NOT_SERVED, "P": Command.NOT_SERVED,
                    "W": Command.NOT_SERVED, "S": Command.NOT_SERVED}


def parse_command(data: bytes) -> Command:
    """A command characteristic's value: exactly one of bluezone's codes (the phone writes
    them with a TextEncoder, nothing around them)."""
    text = data.decode("utf-8", "replace")
    command = _COMMANDS.get(text)
    if command is None:
        raise ProtocolError(f"Unknown command: {shown(text)!r}")
    return command


# --- what the Pi sends ------------------------------------------------------------------

APP_INFO_KIND: Final = "app_info"
SUMMARY_KIND: Final = "app_summary"


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def app_info_message(rows: Sequence[CatalogRow]) -> list[bytes]:
    """The notifications of an `app_info` message: bluezone's keys, in its order, every
    value a string and `yes`/`no` for the flags (the phone shows them as they are); a
    row of the status report is an app of a repository, as LPAM's `-d` table had it."""
    contents = [{"repository": row.repository, "branch": row.ref, "app": row.app,
                 "service": row.named_service, "enabled": _yes(row.installed),
                 "running": _yes(row.running), "description": row.description}
                for row in rows]
    return encode_message(APP_INFO_KIND, contents)


def summary_message(summary: Mapping[str, str]) -> list[bytes]:
    """The answer to `ReadSummary`: a flat object of strings, the app list's style."""
    return encode_message(SUMMARY_KIND, dict(summary))
