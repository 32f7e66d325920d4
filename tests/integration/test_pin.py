"""`lpam pin`: branches and tags of a desired-state file become the commits they point at
now, against a real git daemon; everything else in the file stays byte for byte."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import Lpam, apps_repo

DOCUMENT = """\
# The lab's desired state: reviewed on Fridays.
version: 1

repositories:
  - url: "{apps}"      # the apps, served by the lab laptop
    ref: 'main'
  - url: {tools}
    name: tools
    ref: v1                           # a tag
  - url: {pinned}
    name: pinned
    ref: {commit}
app:
  name: alpha
  params: {{RATE_HZ: "10"}}   # quoted on purpose
"""


def test_pin_rewrites_only_the_refs_and_keeps_comments_order_and_quoting(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
) -> None:
    apps = make_repo("apps.git")
    head = apps_repo(apps)
    tools = make_repo("tools.git")
    tagged = tools.commit("tools", {"README": "tools\n"})
    tools.tag("v1")
    tools.commit("after the tag", {"README": "newer\n"})
    tools.push()
    lib = make_repo("lib.git")
    fixed = lib.commit("lib", {"README": "lib\n"})
    lib.push()
    path = tmp_path / "desired.yaml"
    before = DOCUMENT.format(apps=git_daemon.url("apps.git"), tools=git_daemon.url("tools.git"),
                             pinned=git_daemon.url("lib.git"), commit=fixed)
    path.write_text(before)
    lpam = Lpam(tmp_path / "root")
    dry = lpam("pin", str(path), "--dry-run")
    assert dry.returncode == 0, dry.stderr
    assert path.read_text() == before
    done = lpam("pin", str(path))
    assert done.returncode == 0, done.stderr
    assert f"apps: main → {head}" in done.stdout and f"tools: v1 → {tagged}" in done.stdout
    after = path.read_text()
    expected = before.replace("ref: 'main'", f"ref: '{head}' # pinned from main") \
        .replace("ref: v1                           # a tag",
                 f"ref: {tagged}                           # a tag")
    assert len(before.splitlines()) == len(after.splitlines())  # no line added or lost
    changed = [(a, b) for a, b in zip(before.splitlines(), after.splitlines())
               if a != b]
    assert len(changed) == 2, changed  # the two refs, nothing else
    assert all(head in b or tagged in b for _, b in changed)
    assert "# the apps, served by the lab laptop" in after and 'RATE_HZ: "10"' in after
    assert "# a tag" in after and expected.count(head) == after.count(head)
    assert f"ref: {fixed}\n" in after  # already a full commit: left alone
    again = lpam("pin", str(path))
    assert again.returncode == 0 and "already pinned" in again.stdout
    assert lpam("validate", str(path)).returncode == 0


def test_pin_refuses_a_ref_that_does_not_exist_and_changes_nothing(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
) -> None:
    apps_repo(make_repo("apps.git"))
    path = tmp_path / "desired.yaml"
    text = f"version: 1\nrepositories:\n  - url: {git_daemon.url('apps.git')}\n    ref: nope\n"
    path.write_text(text)
    done = Lpam(tmp_path / "root")("pin", str(path))
    assert done.returncode == 1 and "nope does not exist" in done.stderr
    assert path.read_text() == text


def test_pin_composes_the_file_once(
    tmp_path: Path, make_repo: Callable[[str], RepoBuilder], git_daemon: GitDaemon,
) -> None:
    """The tree validated is the tree rewritten (its quotes kept, as the first test holds):
    `lpam pin --catalogs` reads and composes the desired state once (issue 32 item 2)."""
    from unittest import mock

    from ruamel.yaml.composer import Composer

    from reconciler.base.layout import Layout
    from reconciler.workflow.machine import Machine
    from reconciler.workflow.pin import pin

    apps = make_repo("apps.git")
    head = apps_repo(apps)
    path = tmp_path / "desired.yaml"
    path.write_text(f'version: 1\nrepositories:\n  - url: "{git_daemon.url("apps.git")}"\n'
                    "    ref: 'main'\napp:\n  name: alpha\n")
    with mock.patch.object(Composer, "get_single_node", autospec=True,
                           side_effect=Composer.get_single_node) as composed:
        done = pin(Machine.at(Layout(tmp_path / "root")), path, report=lambda event: None,
                   catalogs=True)
    assert [p.commit for p in done] == [head]
    assert f"ref: '{head}'  # pinned from main" in path.read_text()  # quotes kept
    assert composed.call_count == 2  # the desired state, and the apps' catalog (--catalogs)
