"""reconciler/base/text.py: what lpam echoes from outside is one safe line."""

from __future__ import annotations

from reconciler.base.errors import LpamError
from reconciler.base.text import escaped, printable, shorten


def test_control_characters_are_replaced_never_passed_to_the_terminal() -> None:
    assert printable("a\x1b[2Jb\rc\nd") == "a?[2Jb?c?d"
    assert printable("tab\there", " ") == "tab here"
    assert printable("ünïcode ok") == "ünïcode ok"


def test_escaped_says_which_character_it_was() -> None:
    assert escaped("dir/\x1b[31mred\x07") == "dir/\\x1b[31mred\\x07"


def test_shorten_cuts_the_middle_and_says_how_much() -> None:
    assert shorten("short", 10) == "short"
    long = "a" * 300 + "TAIL"
    cut = shorten(long, 100)
    assert len(cut) < 140 and cut.endswith("TAIL") and "characters left out" in cut


def test_an_error_renders_its_details_terminal_safe() -> None:
    rendered = LpamError("failed", details=["out\x1b]0;title\x07put"]).render()
    assert "\x1b" not in rendered and "\x07" not in rendered and "out?]0;title?put" in rendered


def test_a_count_of_one_is_singular() -> None:
    """'1 apps', '1 repositories' (issue 30, item 14)."""
    from reconciler.base.text import counted

    assert [counted(n, "app") for n in (0, 1, 2)] == ["0 apps", "1 app", "2 apps"]
    assert counted(1, "repository", "repositories") == "1 repository"
    assert counted(3, "repository", "repositories") == "3 repositories"
