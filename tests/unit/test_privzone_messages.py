"""reconciler/core/privzone/messages.py: each phone message becomes one typed request or one
status text, and no value the phone sends reaches lpam unless the desired state would
accept it too."""

from __future__ import annotations

import json
from typing import Any

import pytest

from reconciler.base.errors import LpamError
from reconciler.core.privzone.framing import encode_status, utf16_length
from reconciler.core.privzone.messages import (
    AddRepository,
    AppEnable,
    AppParams,
    AppUpdate,
    Command,
    Failure,
    NotServed,
    ProtocolError,
    ReadSummary,
    RemoveRepository,
    Status,
    Unit,
    app_info_message,
    parse_command,
    parse_input,
    parse_unit,
    summary_message,
    temperature_text,
    unit_value,
)
from schemas.desired import PARAM_VALUE_LIMIT
from schemas.operator import OperatorAction
from tests.records import lpam_row

EMOJI = "\U0001f697"


def phone(kind: str, contents: object) -> bytes:
    """A body as the phone builds it: contents JSON.stringify'd, length in UTF-16 units."""
    text = contents if isinstance(contents, str) else json.dumps(contents, ensure_ascii=False)
    return json.dumps({"type": kind, "contents": text, "length": utf16_length(text)},
                      ensure_ascii=False).encode()


def refusal(body: bytes) -> str:
    with pytest.raises(ProtocolError) as caught:
        parse_input(body)
    return caught.value.text


# --- what is served ---------------------------------------------------------------------

@pytest.mark.parametrize("body, request_", [
    (phone("app_enable", {"app": "pandarecord"}), AppEnable("pandarecord")),
    (phone("app_enable", {"app": "None"}), AppEnable(None)),
    (phone("app_enable", {"app": "gps2vsl_v1.2+rc"}), AppEnable("gps2vsl_v1.2+rc")),
    (phone("app_update", {}), AppUpdate()),
    (phone("app_update", ""), AppUpdate()),
    (phone("app_add_repository", {"repository": "jmscslgroup/libpanda-default-apps",
                                  "branch": "main"}),
     AddRepository("jmscslgroup/libpanda-default-apps", "main")),
    (phone("app_add_repository", {"repository": "o/r", "branch": ""}), AddRepository("o/r", None)),
    (phone("app_add_repository", {"repository": "o/r"}), AddRepository("o/r", None)),
    (phone("app_add_repository", {"repository": "o/r.js", "branch": "feature/x-1.2"}),
     AddRepository("o/r.js", "feature/x-1.2")),
    (phone("app_remove_repository", {"repository": "jmscslgroup/x"}),
     RemoveRepository("jmscslgroup/x")),
    (phone("app_remove_repository", {"repository": "localapps"}), RemoveRepository("localapps")),
    (phone("app_params", {"app": "gps2vsl", "params": {"RATE_HZ": "10", "NOTE": f"é{EMOJI}"}}),
     AppParams("gps2vsl", {"RATE_HZ": "10", "NOTE": f"é{EMOJI}"})),
    (phone("app_params", {"app": "gps2vsl", "params": {}}), AppParams("gps2vsl", {})),
    (phone("app_summary", {}), ReadSummary()),
    (phone("wifi_add", {"ssid": "lab", "psk": "secret"}), NotServed("wifi_add")),
    (phone("wifi_remove", {"ssid": "lab"}), NotServed("wifi_remove")),
    (phone("zonefile", {"vin": "X"}), NotServed("zonefile")),
])
def test_each_request_the_phone_sends(body: bytes, request_: object) -> None:
    assert parse_input(body) == request_


def test_a_not_served_request_carries_no_password() -> None:
    request = parse_input(phone("wifi_add", {"ssid": "lab", "psk": "hunter2"}))
    assert "hunter2" not in repr(request)


def test_the_length_is_javascripts_where_bluezone_counted_pythons() -> None:
    contents = json.dumps({"app": "a", "params": {"NOTE": EMOJI}}, ensure_ascii=False)
    assert parse_input(phone("app_params", contents)) == AppParams("a", {"NOTE": EMOJI})
    by_python = json.dumps({"type": "app_params", "contents": contents,
                            "length": len(contents)}).encode()
    assert refusal(by_python) == (f"Upload issue, length mismatch! ({len(contents)} announced, "
                                  f"{len(contents) + 1} received)")


# --- what is refused, each with one text ------------------------------------------------

def envelope(**fields: object) -> bytes:
    return json.dumps(fields).encode()


@pytest.mark.parametrize("body, text", [
    (b"\xff\xfe{", "File format error! Not UTF-8 text (byte 0)"),
    (b'{"type": "app_enable"', "File format error! Not JSON: Expecting ',' delimiter at "
                               "character 21"),
    (b"[" * 100_000, "File format error! Not JSON: nested too deeply"),
    (b"", "File format error! Not JSON: Expecting value at character 0"),
    (b'["app_enable"]', "File format error! Not a JSON object"),
    (envelope(length=2, contents="{}"), "Key error, missing 'type' in JSON!"),
    (envelope(type="app_update", contents="{}"), "Key error, missing 'length' in JSON!"),
    (envelope(type="app_update", length=2), "Key error, missing 'contents' in JSON!"),
    (envelope(type=["app_update"], length=2, contents="{}"), "Key error, 'type' must be a string"),
    (envelope(type="app_update", length="2", contents="{}"),
     "Key error, 'length' must be a whole number"),
    (envelope(type="app_update", length=True, contents="{}"),
     "Key error, 'length' must be a whole number"),
    (envelope(type="app_update", length=2, contents={}),
     "Key error, 'contents' must be a string of JSON"),
    (envelope(type="app_update", length=3, contents="{}"),
     "Upload issue, length mismatch! (3 announced, 2 received)"),
    (phone("app_destroy", {}), "Unregognized type: app_destroy"),
    (phone("app_enable", "not json"),
     "Error enabling app: 'contents' is not JSON: Expecting value at character 0"),
    (phone("app_enable", ["pandarecord"]), "Error enabling app: 'contents' is not a JSON object"),
    (phone("app_enable", {}), "Error enabling app: missing 'app'"),
    (phone("app_enable", {"app": 3}), "Error enabling app: 'app' must be a string"),
    (phone("app_enable", {"app": "a", "force": True}), "Error enabling app: unknown field 'force'"),
    (phone("app_add_repository", {"repository": "o/r", "branch": 7}),
     "Error adding repository: 'branch' must be a string"),
    (phone("app_add_repository", {"branch": "main"}), "Error adding repository: missing "
                                                      "'repository'"),
    (phone("app_params", {"app": "a", "params": ["X"]}),
     "Error setting app parameters: 'params' must be an object of names to strings"),
    (phone("app_params", {"app": "a", "params": {"X": 1}}),
     "Error setting app parameters: params.X must be a string"),
    (phone("app_params", {"app": "None", "params": {}}),
     "Error setting app parameters: 'app' must name an app, not None"),
])
def test_each_fault_gets_one_text(body: bytes, text: str) -> None:
    assert refusal(body) == text
    assert encode_status(text) == text.encode()  # fits one notification, as it is


INJECTIONS = ["x; reboot", "$(id)", "a`id`", "a|b", "a&b", "-rf", "a b", "a\tb", "a\nb",
              "a\x00b", "../etc", "a..b", ".hidden", "—dash", "app\u202e"]


@pytest.mark.parametrize("value", INJECTIONS)
def test_app_names_the_desired_state_would_refuse_are_refused(value: str) -> None:
    text = refusal(phone("app_enable", {"app": value}))
    assert text.startswith("Error enabling app: app '") and "app names use" in text
    text = refusal(phone("app_params", {"app": value, "params": {}}))
    assert text.startswith("Error setting app parameters: app '")


@pytest.mark.parametrize("value", [*INJECTIONS, "owner", "o/r/x", "o/.r", "-o/r", "o/-r",
                                   "https://github.com/o/r", "git@github.com:o/r", "/srv/r"])
def test_repositories_other_than_owner_slash_name_are_refused(value: str) -> None:
    text = refusal(phone("app_add_repository", {"repository": value, "branch": "main"}))
    assert text.startswith("Error adding repository: repository '") and "owner/name" in text


@pytest.mark.parametrize("value", ["x; reboot", "-o", "a b", "o/r/x", "a..b", "$(id)"])
def test_a_removal_names_a_repository_as_the_desired_state_does(value: str) -> None:
    text = refusal(phone("app_remove_repository", {"repository": value}))
    assert text.startswith("Error removing repository: repository '")


@pytest.mark.parametrize("value", ["-f", "--upload-pack=touch /tmp/x", "a..b", "a b", "x;y",
                                   "main.lock", "a//b", "ref@{0}", "$(id)", "end/"])
def test_branches_git_or_a_shell_could_misread_are_refused(value: str) -> None:
    text = refusal(phone("app_add_repository", {"repository": "o/r", "branch": value}))
    assert text.startswith("Error adding repository: branch '") and "branch" in text


@pytest.mark.parametrize("params, fault", [
    ({"PATH": "/tmp"}, "would change how the app's scripts run"),
    ({"LD_PRELOAD": "/tmp/x.so"}, "would change how the app's scripts run"),
    ({"BASH_ENV": "/tmp/x"}, "would change how the app's scripts run"),
    ({"1X": "a"}, "must look like an environment variable"),
    ({"A-B": "a"}, "must look like an environment variable"),
    ({"X": "a\x00b"}, "contains a NUL byte"),
    ({"X": "a" * (PARAM_VALUE_LIMIT + 1)}, f"longer than {PARAM_VALUE_LIMIT} characters"),
])
def test_parameters_follow_the_desired_states_rules(params: dict[str, str], fault: str) -> None:
    text = refusal(phone("app_params", {"app": "gps2vsl", "params": params}))
    assert text.startswith("Error setting app parameters: params: ") and fault in text


@pytest.mark.parametrize("body", [
    b'{"type": "app_update",\x00 "length": 2, "contents": "{}"}',  # a NUL from a bad write
    b'{"type": "app_update", "length": 1' + b"0" * 5000 + b', "contents": "{}"}',
])
def test_what_a_phone_never_sends_is_refused_as_a_format_or_length_fault(body: bytes) -> None:
    assert refusal(body).startswith(("File format error! Not JSON: ",
                                     "Upload issue, length mismatch!"))  # no digit limit


def test_a_value_echoed_to_the_phone_is_short_and_printable() -> None:
    text = refusal(phone("x\x1b[2J" * 300, {}))
    assert text.startswith("Unregognized type: x?[2Jx?[2J") and "characters left out" in text
    assert text.isprintable() and len(text) < 100


def test_a_protocol_error_is_an_lpam_error_with_one_bounded_line() -> None:
    error = ProtocolError("Unregognized type: " + "x\n" * 1000)
    assert isinstance(error, LpamError)
    assert "\n" not in error.text and len(error.text) < 500


# --- statuses ---------------------------------------------------------------------------

def test_the_phone_refreshes_its_app_list_on_exactly_these_texts() -> None:
    refreshing = {"App command success!", "Repository updated!", "Repository removed!"}
    assert refreshing == Status.REFRESHING
    assert Status.APP_COMMAND_SUCCESS == "App command success!"
    assert Status.REPOSITORY_UPDATED == "Repository updated!"
    assert Status.REPOSITORY_REMOVED == "Repository removed!"
    assert Status.APP_UPDATED == "App updated!"
    assert Status.HELLO == "Hello from the Pi!"


def test_failures_keep_bluezones_words_and_say_why() -> None:
    assert Status.enabling_failed("pandarecord", "no such app") == \
        "Error enabling app pandarecord: no such app"
    assert Status.enabling_failed(None, "busy") == "Error enabling app None: busy"
    assert Failure.STOPPING.because("stop.sh exited 1") == \
        "Error stopping app: stop.sh exited 1"
    assert Failure.RESTARTING.because("x") == "Error restarting app: x"
    assert Failure.ADDING.because("x") == "Error adding repository: x"
    assert Failure.REMOVING.because("x") == "Error removing repository: x"
    assert Failure.UPDATING.because("x") == "Error updating app: x"
    for text in (Status.enabling_failed("a", "b"), *(f.because("x") for f in Failure),
                 Status.not_served("wifi_add")):
        assert text not in Status.REFRESHING
    assert "wifi_add" in Status.not_served("wifi_add")


# --- commands ---------------------------------------------------------------------------

@pytest.mark.parametrize("data, command, action", [
    (b"A", Command.INFO, None),
    (b"As", Command.STOP, OperatorAction.STOP),
    (b"Ar", Command.RESTART, OperatorAction.RESTART),
    (b"R", Command.NOT_SERVED, None), (b"P", Command.NOT_SERVED, None),
    (b"W", Command.NOT_SERVED, None), (b"S", Command.NOT_SERVED, None),
])
def test_commands(data: bytes, command: Command, action: OperatorAction | None) -> None:
    assert parse_command(data) is command
    assert command.action == action


@pytest.mark.parametrize("data, text", [
    (b"a", "Unknown command: 'a'"), (b"A ", "Unknown command: 'A '"),
    (b"", "Unknown command: ''"), (b"As\x00", "Unknown command: 'As?'"),
    (b"\xff", "Unknown command: '\ufffd'"), (b"not served", "Unknown command: 'not served'"),
])
def test_other_commands_are_refused_with_a_text(data: bytes, text: str) -> None:
    with pytest.raises(ProtocolError) as caught:
        parse_command(data)
    assert caught.value.text == text


# --- what the Pi sends ------------------------------------------------------------------

def received(notifications: list[bytes]) -> tuple[Any, str]:
    body = json.loads(b"".join(notifications)[:-1])
    assert body["length"] == utf16_length(body["contents"])
    return json.loads(body["contents"]), str(body["type"])


def test_the_app_list_has_bluezones_keys_order_and_yes_no() -> None:
    rows = [lpam_row("jmscslgroup/libpanda-default-apps", "main", "pandarecord", "pandarecord",
                   True, False, 'GPS/CAN "data" recording'),
            lpam_row("o/r", "dev", "gps2vsl", "can", False, True, f"車 {EMOJI}")]
    contents, kind = received(app_info_message(rows))
    assert kind == "app_info"
    assert contents == [
        {"repository": "jmscslgroup/libpanda-default-apps", "branch": "main",
         "app": "pandarecord", "service": "pandarecord", "enabled": "yes", "running": "no",
         "description": 'GPS/CAN "data" recording'},
        {"repository": "o/r", "branch": "dev", "app": "gps2vsl", "service": "can",
         "enabled": "no", "running": "yes", "description": f"車 {EMOJI}"},
    ]
    assert isinstance(contents, list)
    assert [list(row) for row in contents] == [["repository", "branch", "app", "service",
                                                "enabled", "running", "description"]] * 2
    assert received(app_info_message([])) == ([], "app_info")


def test_the_summary_is_a_flat_object_of_strings() -> None:
    assert received(summary_message({"applied": "abc123", "gates": "open"})) == \
        ({"applied": "abc123", "gates": "open"}, "app_summary")


# --- the thermometer --------------------------------------------------------------------

@pytest.mark.parametrize("millidegrees, fahrenheit, text", [
    (48312, False, "48.3 C"), (48312, True, "119.0 F"), (50000, False, "50.0 C"),
    (47850, False, "47.9 C"), (0, True, "32.0 F"), (-5000, False, "-5.0 C"),
    (61234, True, "142.2 F"),
])
def test_temperature_text_is_bluezones(millidegrees: int, fahrenheit: bool, text: str) -> None:
    assert temperature_text(millidegrees, fahrenheit) == text
    # bluezone: gpiozero's float(millidegrees) / 1000, then str(round(t, 1)) + " " + unit
    degrees = millidegrees / 1000
    expected = str(round(degrees * 1.8 + 32 if fahrenheit else degrees, 1))
    assert text == f"{expected} {'F' if fahrenheit else 'C'}"


@pytest.mark.parametrize("data, unit", [
    (b"C", Unit.CELSIUS), (b"c", Unit.CELSIUS), (b"F", Unit.FAHRENHEIT),
    (b"fahrenheit", Unit.FAHRENHEIT), (b"Celsius", Unit.CELSIUS),
    (b"K", None), (b"", None), (b"\xff", None),
])
def test_the_unit_is_read_from_its_first_byte_as_bluezone_did(data: bytes,
                                                              unit: Unit | None) -> None:
    assert parse_unit(data) is unit


def test_the_unit_reads_back_as_one_letter() -> None:
    assert unit_value(Unit.CELSIUS) == b"C" and unit_value(Unit.FAHRENHEIT) == b"F"
