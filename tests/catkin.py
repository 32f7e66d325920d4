"""Tiny catkin packages for the workspace tests, written the way a person writes one.

Nothing here needs roscpp or rospy (this machine has Debian's catkin and roslaunch, not a
ROS distribution): a node is a plain Python script that roslaunch runs like any other.
It appends `<package> <its own real path>` to the file named by `$TALKER_MARKS`, so a
test can tell which build's sources a launch ran, and then sleeps until it is stopped.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

MARK_VAR = "TALKER_MARKS"
COMPILE_ERROR = "lpam_undeclared_symbol"  # the name the broken package's source lacks

PACKAGE_XML = """\
<?xml version="1.0"?>
<package format="2">
  <name>{name}</name>
  <version>0.1.0</version>
  <description>A package lpam's tests build.</description>
  <maintainer email="lpam@example.com">lpam tests</maintainer>
  <license>MIT</license>
  <buildtool_depend>catkin</buildtool_depend>
</package>
"""

CMAKELISTS = """\
cmake_minimum_required(VERSION 3.0.2)
project({name})
find_package(catkin REQUIRED)
catkin_package()
"""

BROKEN = """\
add_executable({name}_broken src/broken.cpp)
"""

BROKEN_SOURCE = f"int main() {{ return {COMPILE_ERROR}; }}\n"

NODE = """\
#!/usr/bin/env python3
\"\"\"A test node of package {name}: says it started, then sleeps until it is stopped.\"\"\"
import os
import time

with open(os.environ["{var}"], "a") as out:
    out.write("{name} " + os.path.realpath(__file__) + "\\n")
time.sleep(3600)
"""

LAUNCH = """\
<launch>
{nodes}</launch>
"""


def write_package(
    dest: Path, name: str, *, broken: bool = False, launch: str | None = None,
    node: str | None = None,
) -> Path:
    """Write the package `name` into the new folder `dest`; returns `dest`.

    `broken` adds a C++ executable whose source does not compile; `launch` a file
    `launch/<launch>` that starts `node` (if given), the script `scripts/<node>`."""
    dest.mkdir(parents=True)
    (dest / "package.xml").write_text(PACKAGE_XML.format(name=name))
    cmake = CMAKELISTS.format(name=name)
    if broken:
        cmake += BROKEN.format(name=name)
        (dest / "src").mkdir()
        (dest / "src" / "broken.cpp").write_text(BROKEN_SOURCE)
    (dest / "CMakeLists.txt").write_text(cmake)
    if node is not None:
        script = dest / "scripts" / node
        script.parent.mkdir()
        script.write_text(NODE.format(name=name, var=MARK_VAR))
        os.chmod(script, 0o755)
    if launch is not None:
        nodes = "" if node is None else \
            f'  <node pkg="{name}" type="{node}" name="{_ros_name(node)}" output="screen"/>\n'
        (dest / "launch").mkdir()
        (dest / "launch" / launch).write_text(LAUNCH.format(nodes=nodes))
    return dest


def _ros_name(script: str) -> str:
    """A node name ROS accepts, from the script's file name."""
    return re.sub(r"\W", "_", script.removesuffix(".py")) or "node"
