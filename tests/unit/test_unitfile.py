"""Rendering of systemd units: every awkward value reads back as written.

Two independent readers check each rendered unit: systemd itself (`systemd-analyze verify`,
offline; its stderr must be empty, and it finds the ExecStart program only if the path
was quoted right) and a small reader written from systemd.syntax(7) and
systemd.service(5) below, which decodes the words in both orders systemd versions use
(unquote then specifiers, v245+; specifiers then unquote, older).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reconciler.adapters.services.unitfile import (
    HEADER,
    environment_assignment,
    exec_line,
    render_unit,
)
from reconciler.base.unit import Unit

PROGRAM = os.path.realpath(sys.executable)
AWKWARD = [
    "plain",
    "two words",
    "",
    'say "hi"',
    "it's",
    "100%",
    "%n %i %%",  # %n is a real specifier: unescaped it would become the unit's name
    "$HOME",
    "${HOME}",
    "$$",
    "cost: $5",
    "back\\slash",
    "trailing\\",
    "\\n is two characters",
    "tab\there",
    ";",
    "\\;",
    "--",
    "-x",
    "é 漢字 🚗",
    "  padded  ",
    "a=b=c",
]


# -- a reader of unit files, from systemd.syntax(7) -----------------------------------

_C_ESCAPES = {"a": "\a", "b": "\b", "f": "\f", "n": "\n", "r": "\r", "t": "\t", "v": "\v",
              "\\": "\\", '"': '"', "'": "'", "s": " "}


def unquote(text: str) -> list[str]:
    """Words as systemd's extract_first_word(EXTRACT_UNQUOTE | EXTRACT_CUNESCAPE) splits
    them: whitespace separates, quotes group, C escapes inside and outside quotes."""
    words: list[str] = []
    i, n = 0, len(text)
    while True:
        while i < n and text[i] in " \t\n":
            i += 1
        if i >= n:
            return words
        word: list[str] = []
        quote: str | None = None
        while i < n and (quote is not None or text[i] not in " \t\n"):
            ch = text[i]
            if ch == "\\":
                i += 1
                if i >= n:
                    raise ValueError("backslash at the end")
                if text[i] == "x":
                    word.append(chr(int(text[i + 1:i + 3], 16)))
                    i += 2
                elif text[i] in _C_ESCAPES:
                    word.append(_C_ESCAPES[text[i]])
                else:
                    raise ValueError(f"unknown escape \\{text[i]}")
            elif quote is not None and ch == quote:
                quote = None
            elif quote is None and ch in "\"'":
                quote = ch
            else:
                word.append(ch)
            i += 1
        if quote is not None:
            raise ValueError("unbalanced quoting")
        words.append("".join(word))


def specifiers(text: str) -> str:
    """`%%` → `%`; any other specifier would expand to something lpam did not write."""
    out, i = [], 0
    while i < len(text):
        if text[i] == "%":
            if text[i + 1:i + 2] != "%":
                raise ValueError(f"specifier %{text[i + 1:i + 2]} would be expanded")
            out.append("%")
            i += 2
        else:
            out.append(text[i])
            i += 1
    return "".join(out)


def dollars(word: str) -> str:
    """`$$` → `$` as systemd does when it runs the command; a lone `$` could expand."""
    out, i = [], 0
    while i < len(word):
        if word[i] == "$":
            if word[i + 1:i + 2] != "$":
                raise ValueError(f"{word!r} holds a variable reference")
            out.append("$")
            i += 2
        else:
            out.append(word[i])
            i += 1
    return "".join(out)


def read_exec(value: str) -> list[str]:
    """An ExecStart= value as the argv systemd runs, decoded in both orders."""
    new = [specifiers(w) for w in unquote(value)]
    old = unquote(specifiers(value))
    assert new == old
    return [new[0], *(dollars(w) for w in new[1:])]


def read_environment(value: str) -> dict[str, str]:
    words = [specifiers(w) for w in unquote(value)]
    assert words == unquote(specifiers(value))
    return dict(w.split("=", 1) for w in words)


def sections(text: str) -> dict[str, list[tuple[str, str]]]:
    """A unit file's sections as (key, value) pairs, continuation lines joined."""
    result: dict[str, list[tuple[str, str]]] = {}
    current = ""
    logical = ""
    for raw in text.splitlines():
        if raw.endswith("\\"):
            logical += raw[:-1] + " "
            continue
        line, logical = (logical + raw).strip(), ""
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            current = line.strip("[]")
            result.setdefault(current, [])
            continue
        key, _, value = line.partition("=")
        result[current].append((key.strip(), value.strip()))
    return result


def values(text: str, section: str, key: str) -> list[str]:
    return [v for k, v in sections(text)[section] if k == key]


# -- systemd's own reading -------------------------------------------------------------

def verify(directory: Path, text: str, name: str = "lpam-app-x") -> str:
    """`systemd-analyze verify` of `text` as `<directory>/<name>.service`: its stderr."""
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze is not installed")
    path = directory / f"{name}.service"
    path.write_text(text, encoding="utf-8")
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LANG": "C.UTF-8",
           "SYSTEMD_LOG_COLOR": "0", "HOME": str(directory)}
    proc = subprocess.run([tool, "verify", str(path)], capture_output=True, text=True,
                          timeout=60, env=env, cwd=directory, check=False)
    return proc.stderr


def unit(tmp_path: Path, **changes: object) -> Unit:
    fields: dict[str, object] = {"name": "lpam-app-x", "argv": (PROGRAM, "-c", "pass"),
                                 "directory": tmp_path}
    fields.update(changes)
    return Unit(**fields)  # type: ignore[arg-type]


# -- tests -------------------------------------------------------------------------------

def test_plain_unit_has_every_promise(tmp_path: Path) -> None:
    text = render_unit(unit(tmp_path, description="lpam app demo (abc)"))
    assert text.startswith(HEADER + "\n")
    assert sections(text) == {
        "Unit": [("Description", "lpam app demo (abc)"),
                 ("Wants", "network-online.target"), ("After", "network-online.target"),
                 ("StartLimitIntervalSec", "60s"), ("StartLimitBurst", "5")],
        "Service": [("Type", "simple"), ("ExecStart", f'"{PROGRAM}" "-c" "pass"'),
                    ("WorkingDirectory", str(tmp_path)), ("Restart", "on-failure"),
                    ("RestartSec", "2s"), ("KillMode", "control-group"),
                    ("TimeoutStopSec", "10s"), ("StandardOutput", "journal"),
                    ("StandardError", "journal")],
        "Install": [("WantedBy", "multi-user.target")],
    }
    assert verify(tmp_path, text) == ""


def test_awkward_arguments_and_environment_read_back(tmp_path: Path) -> None:
    env = {f"V{i}": value for i, value in enumerate(AWKWARD)}
    text = render_unit(unit(tmp_path, argv=(PROGRAM, *AWKWARD), environment=env, user="root",
                            description="100% awkward \\ \"unit\"\nsecond line\\"))
    assert read_exec(values(text, "Service", "ExecStart")[0]) == [PROGRAM, *AWKWARD]
    read: dict[str, str] = {}
    for value in values(text, "Service", "Environment"):
        read.update(read_environment(value))
    assert read == env
    assert values(text, "Service", "User") == ["root"]
    assert values(text, "Unit", "Description") == ['100%% awkward \\ "unit" second line']
    assert verify(tmp_path, text) == ""


def test_environment_is_sorted_so_the_file_changes_only_with_its_content(
    tmp_path: Path,
) -> None:
    one = render_unit(unit(tmp_path, environment={"B": "2", "A": "1"}))
    two = render_unit(unit(tmp_path, environment={"A": "1", "B": "2"}))
    assert one == two
    assert values(one, "Service", "Environment") == ['"A=1"', '"B=2"']


@pytest.mark.parametrize("name", ["with space", "100%", "%n", "semi;colon", "é漢字🚗",
                                  "a=b", "-dash", "tab"])
def test_systemd_finds_the_program_at_an_awkward_path(tmp_path: Path, name: str) -> None:
    """systemd-analyze checks that ExecStart's program exists: it reads our quoting."""
    folder = tmp_path / f"odd {name}"
    folder.mkdir()
    program = folder / name
    program.write_text("#!/bin/sh\n")
    program.chmod(0o755)
    text = render_unit(unit(tmp_path, argv=(str(program), name), directory=folder))
    assert verify(tmp_path, text) == ""
    assert read_exec(values(text, "Service", "ExecStart")[0]) == [str(program), name]


def test_verify_does_complain_about_a_missing_program(tmp_path: Path) -> None:
    """The check above means something: a path systemd cannot find is reported."""
    text = render_unit(unit(tmp_path, argv=(str(tmp_path / "no such"),)))
    assert "is not executable" in verify(tmp_path, text)


def test_times_in_whole_seconds_or_milliseconds(tmp_path: Path) -> None:
    text = render_unit(unit(tmp_path, restart_seconds=0.5, stop_seconds=90.0,
                            start_limit=0, start_limit_seconds=1.25))
    assert values(text, "Service", "RestartSec") == ["500ms"]
    assert values(text, "Service", "TimeoutStopSec") == ["90s"]
    assert values(text, "Unit", "StartLimitIntervalSec") == ["1250ms"]
    assert values(text, "Unit", "StartLimitBurst") == ["0"]
    assert verify(tmp_path, text) == ""


def test_a_trailing_backslash_never_continues_into_the_next_key(tmp_path: Path) -> None:
    text = render_unit(unit(tmp_path, description="ends in \\",
                            argv=(PROGRAM, "ends in \\"), environment={"E": "ends in \\"}))
    assert values(text, "Unit", "Wants") == ["network-online.target"]
    assert values(text, "Service", "WorkingDirectory") == [str(tmp_path)]
    assert values(text, "Service", "Restart") == ["on-failure"]
    assert verify(tmp_path, text) == ""


@pytest.mark.parametrize(("changes", "message"), [
    ({"argv": (PROGRAM, "line\nbreak")}, "line break"),
    ({"argv": (PROGRAM, "nul\x00")}, "control character"),
    ({"argv": (PROGRAM, "carriage\r")}, "line break"),
    ({"argv": (PROGRAM, "bad \ud800 surrogate")}, "UTF-8"),
    ({"argv": ("python3", "-c")}, "absolute"),
    ({"argv": ("bin/tool",)}, "absolute"),
    ({"argv": ("/opt/dir/",)}, "directory"),
    ({"argv": ('/opt/a"b',)}, "quote"),
    ({"argv": ("/opt/a\\b",)}, "backslash"),
    ({"argv": ("/opt/$app/run",)}, "`\\$`"),
    ({"argv": ("/opt/a\tb",)}, "control character"),
    ({"argv": ()}, "no command"),
    ({"environment": {"A": "x\ny"}}, "line break"),
    ({"environment": {"A": "x\x00"}}, "control character"),
    ({"environment": {"1A": "x"}}, "variable name"),
    ({"environment": {"A-B": "x"}}, "variable name"),
    ({"environment": {"A B": "x"}}, "variable name"),
    ({"directory": Path("relative")}, "absolute"),
    ({"directory": Path("/srv/../etc")}, "absolute"),
    ({"directory": Path("/srv/ends\\")}, "backslash"),
    ({"directory": Path("/srv/ends ")}, "space"),
    ({"directory": Path("/srv/new\nline")}, "line break"),
    ({"user": "no such"}, "user name"),
    ({"user": "root\n"}, "user name"),
    ({"user": "%n"}, "user name"),
    ({"restart_seconds": -1.0}, "restart_seconds"),
    ({"stop_seconds": float("nan")}, "stop_seconds"),
    ({"start_limit_seconds": float("inf")}, "start_limit_seconds"),
    ({"start_limit": -1}, "start_limit"),
    ({"name": "lpam-app-x.service"}, "without `.service`"),
    ({"name": "../../etc/passwd"}, "not a service name"),
    ({"name": "-x"}, "not a service name"),
    ({"environment": {"BIG": "x" * (1024 * 1024)}}, "longer than"),
])
def test_values_systemd_cannot_hold_are_refused(
    tmp_path: Path, changes: dict[str, object], message: str,
) -> None:
    with pytest.raises(ValueError, match=message):
        render_unit(unit(tmp_path, **changes))


_CONTROLS = "".join(chr(c) for c in (*range(0x00, 0x09), *range(0x0A, 0x20), 0x7F))
_TEXT = st.text(st.characters(codec="utf-8", exclude_characters=_CONTROLS), max_size=40)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(st.lists(_TEXT, max_size=6), st.dictionaries(st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}",
                                                                  fullmatch=True), _TEXT,
                                                    max_size=4))
def test_any_printable_text_round_trips(args: list[str], env: dict[str, str]) -> None:
    assert read_exec(exec_line([PROGRAM, *args])) == [PROGRAM, *args]
    for key, value in env.items():
        assert read_environment(environment_assignment(key, value)) == {key: value}


def test_a_launch_app_inside_its_ros_build_reads_back_and_verifies(tmp_path: Path) -> None:
    """The unit of a `launch:` app runs roslaunch through a shell that sources its build's
    setup first: the shell's `$1` and `"$@"` must reach bash, not systemd's expansion."""
    from reconciler.engine.execution.supervision import ROS_WRAPPER

    setup = tmp_path / "ws" / ".lpam" / "builds" / "0123456789abcdef" / "devel" / "setup.bash"
    argv = ("/bin/bash", "-c", ROS_WRAPPER, "lpam-ros", str(setup), "roslaunch",
            "can_to_ros", "vsl.launch")
    text = render_unit(unit(tmp_path, argv=argv, environment={"ROS_HOME": str(tmp_path)}))
    assert read_exec(values(text, "Service", "ExecStart")[0]) == list(argv)
    assert verify(tmp_path, text) == ""
