"""The benchmark's fixture: N small lpam app repositories behind a loopback `git daemon`
that logs every connection, and the same set described for lpam, vcstool and plain git.

The repositories are built with tests/gitserver.py's RepoBuilder so that the benchmark
meets the same server the integration tests do; only the daemon differs, because counting
connections needs `--verbose` and its stderr.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tests.gitserver import GitDaemon, RepoBuilder
from tests.integration.apps import add_app

CATALOG = """\
apps:
  - name: {app}
    path: {app}/
    properties:
      - owns_panda: true
"""


class CountingDaemon(GitDaemon):
    """GitDaemon with `--verbose` into a log file, so that connections can be counted.

    Every connection the daemon accepts logs one "Connection from" line; the count over
    a tool's run is how many times that tool went to the network.
    """

    def __init__(self, base: Path, *, home: Path, log: Path, receive_pack: bool = False) -> None:
        super().__init__(base, home=home, log=log, receive_pack=receive_pack)

    def connections(self) -> int:
        """Connections accepted so far (a tool's count is the difference over its run)."""
        if self.log is None or not self.log.exists():
            return 0
        return self.log.read_text(errors="replace").count("Connection from")



@dataclass(frozen=True)
class Repo:
    name: str  # as served: `<daemon base>/<name>`
    url: str
    tip: str  # full hash of main's last commit


def build_repos(
    daemon: GitDaemon, work: Path, home: Path, *, count: int, commits: int
) -> list[Repo]:
    """`count` distinct repositories of `commits` commits each, every one a valid lpam app
    repository (a catalog with one app folder), pushed to `main` on the daemon."""
    repos = []
    for index in range(count):
        name = f"r{index:02d}.git"
        app = f"app-{index:02d}"
        builder = RepoBuilder(daemon.base, name, work_root=work, home=home)
        builder.write("libpanda-apps.yaml", CATALOG.format(app=app))
        add_app(builder, app)
        tip = builder.commit(f"{app}: first version")
        for number in range(1, commits):
            tip = builder.commit(
                f"{app}: change {number}",
                {f"{app}/data/{number % 7}.txt": f"{name} change {number}\n" * (number + 1)},
            )
        builder.push()
        repos.append(Repo(name=name, url=daemon.url(name), tip=tip))
    return repos


def desired_state(repos: list[Repo], *, pinned: bool) -> str:
    """lpam's desired state: every repository at its tip's hash (or at `main`), no app."""
    lines = ["version: 1", "repositories:"]
    for repo in repos:
        lines += [f"  - url: {repo.url}", f"    ref: {repo.tip if pinned else 'main'}"]
    return "\n".join([*lines, "app: null"]) + "\n"


def repos_file(repos: list[Repo], *, pinned: bool) -> str:
    """The same set as a vcstool `.repos` file."""
    lines = ["repositories:"]
    for repo in repos:
        lines += [
            f"  {repo.name.removesuffix('.git')}:",
            "    type: git",
            f"    url: {repo.url}",
            f"    version: {repo.tip if pinned else 'main'}",
        ]
    return "\n".join(lines) + "\n"
