"""`trust: {allowed_signers: FILE}`: only commits signed by a listed SSH key are applied.
Keys and signatures are made by the real OpenSSH (`ssh-keygen`) and git (`commit -S` with
gpg.format=ssh); lpam checks them with `ssh-keygen -Y verify`."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from tests.gitserver import RepoBuilder
from tests.integration.apps import Lpam
from tests.integration.conftest import fleet_state

pytestmark = pytest.mark.skipif(shutil.which("ssh-keygen") is None,
                                reason="needs OpenSSH's ssh-keygen (openssh-client)")


def keypair(folder: Path, name: str) -> Path:
    key = folder / name
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", name, "-f", str(key)],
                   check=True, capture_output=True)
    return key


def signed_commit(repo: RepoBuilder, key: Path, message: str, files: dict[str, str]) -> str:
    for path, content in files.items():
        repo.write(path, content)
    repo.git("add", "--all")
    repo.git("-c", "gpg.format=ssh", "-c", f"user.signingkey={key}", "commit", "--quiet",
             "-S", "-m", message)
    repo.push()
    return repo.rev("HEAD")


@pytest.fixture
def keys(car: Lpam, tmp_path: Path) -> tuple[Path, Path]:
    """The lab's key (listed in the car's allowed signers) and a stranger's."""
    lab, stranger = keypair(tmp_path, "lab"), keypair(tmp_path, "stranger")
    allowed = car.root / "etc/lpam/allowed_signers"
    allowed.write_text(f"lab@example.org {lab.with_suffix('.pub').read_text()}")
    config = car.root / "etc/lpam/agent.yaml"
    config.write_text(config.read_text() + "trust: {allowed_signers: /etc/lpam/allowed_signers}\n")
    return lab, stranger


def test_only_commits_signed_by_an_allowed_key_are_applied(
    car: Lpam, fleet: RepoBuilder, keys: tuple[Path, Path],
) -> None:
    lab, stranger = keys
    unsigned = car("sync")  # the fleet fixture's first commit is not signed
    assert unsigned.returncode == 1 and "is not signed" in unsigned.stderr
    assert car.events() == []
    good = signed_commit(fleet, lab, "signed by the lab",
                         {"desired-state.yaml": fleet_state("alpha", MODE="lab")})
    done = car("sync")
    assert done.returncode == 0, done.stderr
    assert car.events() == ["alpha:install:lab", "alpha:start:lab"]
    signed_commit(fleet, stranger, "signed by someone else",
                  {"desired-state.yaml": fleet_state("beta")})
    refused = car("sync")
    assert refused.returncode == 1
    assert "is signed by a key not in" in refused.stderr
    assert car.events() == ["alpha:install:lab", "alpha:start:lab"]  # stays on the good one
    assert car.status()["agent"]["applied_revision"] == good


def test_a_signed_commit_altered_afterwards_is_refused(
    car: Lpam, fleet: RepoBuilder, keys: tuple[Path, Path],
) -> None:
    lab, _ = keys
    signed_commit(fleet, lab, "signed", {"desired-state.yaml": fleet_state("alpha")})
    # Rewrite the commit's message but keep its signature header: what a tamperer could do.
    def git(*args: str, stdin: bytes = b"") -> bytes:
        return subprocess.run(["git", *args], input=stdin, cwd=fleet.work, env=fleet.env,
                              capture_output=True, check=True).stdout

    raw = git("cat-file", "commit", "HEAD")
    assert b"-----BEGIN SSH SIGNATURE-----" in raw
    forged = git("hash-object", "-t", "commit", "-w", "--stdin",
                 stdin=raw.replace(b"\nsigned\n", b"\nsigned, then altered\n"))
    git("update-ref", "HEAD", forged.decode().strip())
    fleet.push()
    refused = car("sync")
    assert refused.returncode == 1 and "does not verify" in refused.stderr
    assert car.events() == []
