"""Rules for the names and strings that end up in paths, URLs and git commands.

They are strict on purpose: an app name becomes a directory, a ref and a URL reach git,
and the old tool was exploitable through exactly these strings (lpam-legacy.md).
"""

from __future__ import annotations

import re

# Imported inside functions: urllib.parse (stdlib, ~4 modules) only when a URL is checked; a
# negligible start-up gain.

APP_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,99}$")
OWNER_REPO = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}/[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")
PARAM_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,99}$")
_REF = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_./+-]{0,254}$")
_SHELL = set(" \t\r\n;|&$`<>()'\"\\*?{}[]!^~")
URL_SCHEMES = ("https://", "http://", "git://", "ssh://", "file://")
HEX = re.compile(r"^[0-9a-f]{4,40}$")
_USERINFO = re.compile(r"(?P<scheme>\b[A-Za-z][A-Za-z0-9+.-]*://)(?P<userinfo>[^/@\s]+)@")


def check_app_name(value: str) -> str:
    if ".." in value or not APP_NAME.match(value):
        raise ValueError(
            "app names use letters, digits, '_', '-', '.', '+' (no '/', no '..', "
            "at most 100 characters)"
        )
    return value


def check_owner_repo(value: str) -> str:
    if ".." in value or not OWNER_REPO.match(value):
        if "://" in value or value.startswith(("git@", "/")):
            raise ValueError("expected 'owner/name' (a GitHub repository); a URL or a path "
                             "goes under `url:` instead of `repo:`")
        raise ValueError("expected 'owner/name', e.g. jmscslgroup/libpanda-default-apps")
    return value


def check_ref(value: str) -> str:
    bad = (
        not _REF.match(value)
        or ".." in value
        or "//" in value
        or "@{" in value
        or value.endswith(("/", ".", ".lock"))
    )
    if bad:
        raise ValueError(
            "not a valid branch, tag or commit: use letters, digits and '_ . / + -', "
            "not starting with '-' and without '..'"
        )
    return value


URL_LIMIT = 2048
PART_LIMIT = 200  # a URL's last part names a directory: file names stop at 255 bytes


def check_url(value: str) -> str:
    """A URL or local path lpam can hand to its git client, refused here rather than
    misread there: dulwich sends `host:path` and any URL it cannot parse to the ssh binary."""
    from urllib.parse import urlsplit

    if not value or value.startswith("-"):
        raise ValueError("a URL must not be empty or start with '-'")
    if len(value) > URL_LIMIT:
        raise ValueError(f"the URL is longer than {URL_LIMIT} characters")
    if any(ch in _SHELL or ord(ch) < 32 or 0xD800 <= ord(ch) <= 0xDFFF for ch in value):
        raise ValueError("the URL contains a space, a control or a shell metacharacter")
    if any(len(part.encode("utf-8", "replace")) > PART_LIMIT for part in value.split("/")):
        raise ValueError(f"a part of the URL between '/' is longer than {PART_LIMIT} bytes")
    if "://" not in value:
        if ":" in value:
            raise ValueError("a local path must not contain ':' (git would read 'host:path' "
                             "as ssh); for ssh write ssh://host/path")
        return value
    if not value.startswith(URL_SCHEMES):
        raise ValueError("use an https://, http://, git://, ssh:// or file:// URL, or a path")
    try:
        port = urlsplit(value).port
    except ValueError:
        raise ValueError("the URL's port must be a number from 1 to 65535") from None
    if port == 0:
        raise ValueError("the URL's port must be a number from 1 to 65535")
    return value


UNSAFE_PARAMS = frozenset({
    "BASH_ENV", "ENV", "SHELLOPTS", "BASHOPTS", "PS4", "IFS", "PATH", "CDPATH", "GLOBIGNORE",
    "PROMPT_COMMAND", "NODE_OPTIONS", "PERL5OPT", "PERL5LIB", "RUBYOPT", "RUBYLIB",
})
UNSAFE_PARAM_PREFIXES = ("LD_", "PYTHON", "LPAM_", "BASH_FUNC_", "DYLD_", "GCONV_")


DATA_LIMIT = 20  # globs per app: a few folders, not a file list


def check_data(value: list[str]) -> list[str]:
    """`data:` globs: absolute paths (lpam reads them under its --root), no `..`, few."""
    if len(value) > DATA_LIMIT:
        raise ValueError(f"give at most {DATA_LIMIT} globs")
    for glob in value:
        if not glob.startswith("/") or ".." in glob.split("/") or not glob.isprintable():
            raise ValueError(f"{glob!r}: give an absolute path or glob, without '..', such as "
                             "/var/panda/CyverseData/JmscslgroupData/PandaData/*/*.csv")
    return value


def check_param_name(name: str) -> str:
    """A parameter becomes an environment variable of every app script, and parameters may
    come from a phone over Bluetooth: names that change how bash, the dynamic loader or an
    interpreter starts (BASH_ENV made bash source a file before install.sh; PATH replaced
    commands; LD_PRELOAD, PYTHONPATH…) would let a parameter run code, so they are refused.
    LPAM_* are lpam's own."""
    if not PARAM_NAME.match(name):
        raise ValueError(f"parameter name {name!r} must look like an environment variable "
                         "(letters, digits, '_')")
    upper = name.upper()
    if upper in UNSAFE_PARAMS or upper.startswith(UNSAFE_PARAM_PREFIXES):
        raise ValueError(f"parameter name {name!r} would change how the app's scripts run "
                         "(shell, loader or interpreter settings); choose another name")
    return name


def is_hex_commit(ref: str) -> bool:
    """True for what can only be meant as a commit hash (full or abbreviated)."""
    return bool(HEX.match(ref))


def repository_key(url: str) -> str:
    """The short name of a repository URL, used in plans, the store and `app.repository`.

    A network URL gives its path without the host (`https://github.com/o/n` → `o/n`); a
    local path or file:// URL gives its last component, so that the same folder named
    relatively from two places is still the same repository.
    """
    path = url.rstrip("/")
    local = "://" not in path or path.startswith("file://")
    if not local:
        path = path.split("://", 1)[1].partition("/")[2]
    path = path.removesuffix(".git")
    parts = [p for p in path.split("/") if p not in ("", ".", "..")]
    if not parts:
        return url
    return parts[-1] if local else "/".join(parts[-2:])


def redact(text: str) -> str:
    """`text` with the credentials of every URL in it hidden.

    `https://user:secret@host/…` becomes `https://user:***@host/…`; a lone user part may be
    a token (`https://ghp_…@github.com/…`) and is hidden whole. Used for every URL lpam
    prints: error messages, plans and status go to terminals, logs and phones.
    """

    def hide(match: re.Match[str]) -> str:
        user, sep, _ = match["userinfo"].partition(":")
        return f"{match['scheme']}{user}:***@" if sep else f"{match['scheme']}***@"

    return _USERINFO.sub(hide, text)
