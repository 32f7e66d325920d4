"""Bad dependencies are refused at the document, located at file:line:column, before any
apt-get or pip runs: shell metacharacters, a leading `-` (an option), URLs and paths.
And the desired state's `mirrors:` and `ros:` read as git's insteadOf and a workspace."""

from __future__ import annotations

from pathlib import Path

import pytest

from reconciler.base.errors import ConfigError
from reconciler.core.documents import load_desired, parse_catalog
from schemas.dependency import requirement_name

CATALOG = Path("lab@0123abcd/libpanda-apps.yaml")


@pytest.mark.parametrize(("dependency", "expected"), [
    ("{apt: 'libfoo; rm -rf /'}", "is not a Debian package name"),
    ("{apt: -oAPT::Get=1}", "is not a Debian package name"),
    ("{apt: LibFoo}", "is not a Debian package name"),
    ("{apt: https://example.org/x.deb}", "is not a Debian package name"),
    ("{apt: ./x.deb}", "is not a Debian package name"),
    ("{pip3: --index-url=http://evil}", "not a pip requirement"),
    ("{pip3: 'x @ https://example.org/x.whl'}", "not a pip requirement"),
    ("{pip3: ./local/pkg}", "not a pip requirement"),
    ("{pip3: 'x; os_name == \"nt\"'}", "not a pip requirement"),
    ("{pip3: 'x$(id)'}", "not a pip requirement"),
    ("{apt: aa, pip3: b}", "exactly one of"),
    ("{}", "exactly one of"),
])
def test_bad_dependencies_are_located(dependency: str, expected: str) -> None:
    text = f"apps:\n  - name: vsl\n    dependencies:\n      - {dependency}\n"
    with pytest.raises(ConfigError) as info:
        parse_catalog(CATALOG, text)
    assert expected in info.value.message
    assert info.value.path == CATALOG and info.value.line == 4


def test_good_dependencies_read_back() -> None:
    text = ("apps:\n  - name: vsl\n    dependencies:\n      - apt: libdiagnostic-updater-dev\n"
            "      - apt: libc6:arm64\n      - pip3: shapely>=2,<3\n"
            "      - pip3: requests[socks]==2.31\n    ros_repositories:\n"
            "      - {owner: jmscslgroup, repo: can_to_ros, branch_or_hash: 17dd12e9}\n"
            "      - {owner: lab, repo: drivers, url: 'git://192.168.4.1/drivers'}\n")
    [app] = parse_catalog(CATALOG, text).apps
    assert app.apt == ["libdiagnostic-updater-dev", "libc6:arm64"]
    assert app.pip3 == ["shapely>=2,<3", "requests[socks]==2.31"]
    assert [r.source for r in app.ros_repositories] == [
        "https://github.com/jmscslgroup/can_to_ros", "git://192.168.4.1/drivers"]
    assert requirement_name("Python_CAN>=4") == "python-can"


def test_two_ros_repositories_with_one_name_are_refused() -> None:
    text = ("apps:\n  - name: vsl\n    ros_repositories:\n"
            "      - {owner: a, repo: drivers}\n      - {owner: b, repo: drivers}\n")
    with pytest.raises(ConfigError, match="two ROS repositories are named 'drivers'"):
        parse_catalog(CATALOG, text)


def test_mirrors_replace_the_longest_matching_prefix(tmp_path: Path) -> None:
    path = tmp_path / "desired.yaml"
    path.write_text('version: 1\nmirrors:\n  "https://github.com/": "git://192.168.4.1/"\n'
                    '  "https://github.com/lab/": "file:///media/usb/lab/"\n'
                    "ros: {workspace: /home/circles/catkin_ws, user: circles}\n")
    desired = load_desired(path)
    assert desired.mirrored("https://github.com/jmscslgroup/can_to_ros") == \
        "git://192.168.4.1/jmscslgroup/can_to_ros"
    assert desired.mirrored("https://github.com/lab/apps") == "file:///media/usb/lab/apps"
    assert desired.mirrored("https://gitlab.com/x/y") == "https://gitlab.com/x/y"
    assert (desired.ros.workspace, desired.ros.user) == ("/home/circles/catkin_ws", "circles")


@pytest.mark.parametrize(("document", "expected", "line"), [
    ('mirrors: {"github.com/": "git://h/"}', "both sides must be URL prefixes", 2),
    ('mirrors: {"https://github.com/": "/media/usb"}', "both sides must be URL prefixes", 2),
    ("ros: {workspace: catkin_ws}", "absolute path", 2),
    ("ros: {workspace: /home/../etc}", "absolute path", 2),
    ("ros: {user: 'Bad User'}", "is not a user name", 2),
    ("ros: {distro: noetic}", "distro", 2),
])
def test_bad_mirrors_and_ros_settings_are_located(tmp_path: Path, document: str,
                                                  expected: str, line: int) -> None:
    path = tmp_path / "desired.yaml"
    path.write_text(f"version: 1\n{document}\n")
    with pytest.raises(ConfigError) as info:
        load_desired(path)
    assert expected in info.value.message and info.value.line == line
