"""What an app may ask to be installed for it: Debian packages and pip requirements.

Both end up as arguments of `apt-get` and `pip`, run as root. They are passed as argument
lists, never through a shell, but a value starting with `-` would still be read as an
option (`--index-url=…`, `-o APT::…`), and a URL or path would install something that no
catalog review saw. So only the plain grammars are accepted.
"""

from __future__ import annotations

import re

# Imported inside functions: packaging (~50 modules) loads only when a pip requirement is checked; a
# plan without pip requirements does not pay for it (start-up).

# Debian Policy 5.6.1: lower case letters, digits, '+', '-', '.'; at least two characters,
# starting with a letter or digit. An architecture qualifier (`:arm64`) is allowed.
_DEBIAN = re.compile(r"^[a-z0-9][a-z0-9+.-]{1,99}(:[a-z0-9][a-z0-9-]{0,31})?$")
_REQUIREMENT_CHARS = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-\[\],<>=!~* ]{0,199}$")


def check_debian_package(value: str) -> str:
    """A Debian package name (optionally `:arch`), or ValueError saying what is allowed."""
    if not _DEBIAN.match(value):
        raise ValueError(
            f"{value!r} is not a Debian package name: lower-case letters, digits, '+', '-', "
            "'.', at least two characters, starting with a letter or digit "
            "(e.g. libdiagnostic-updater-dev)"
        )
    return value


def check_requirement(value: str) -> str:
    """A pip requirement specifier: a name, optional extras and version specifiers
    (`cantools`, `shapely>=2,<3`, `requests[socks]==2.31`). No URL, path, marker or option."""
    # packaging is imported here, not at the top: every document load imports this module,
    # and a plan without pip requirements should not pay for it.
    from packaging.requirements import InvalidRequirement, Requirement

    problem = None
    if not _REQUIREMENT_CHARS.match(value):
        problem = "it may hold only a name, [extras] and version specifiers"
    else:
        try:
            requirement = Requirement(value)
        except InvalidRequirement as exc:
            problem = str(exc).splitlines()[0]
        else:
            if requirement.url or requirement.marker:
                problem = "URLs and environment markers are not allowed"
    if problem is not None:
        raise ValueError(
            f"{value!r} is not a pip requirement lpam accepts: {problem} "
            "(e.g. cantools, shapely>=2,<3)"
        )
    return value


def requirement_name(value: str) -> str:
    """The distribution a requirement names, normalised as pip compares them
    (`Shapely` and `shapely` are one distribution; `python_can` is `python-can`)."""
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    return str(canonicalize_name(Requirement(value).name))
