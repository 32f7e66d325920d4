"""Is a commit signed by a key this vehicle trusts? OpenSSH answers; lpam does no
cryptography of its own.

git signs a commit with an SSH key (`gpg.format=ssh`) by putting an SSH signature of the
commit object, without its `gpgsig` header, in that header, in the `git` namespace.
`ssh-keygen -Y find-principals` names who holds the signing key according to an
`allowed_signers` file (OpenSSH's format, as git's `gpg.ssh.allowedSignersFile`), and
`ssh-keygen -Y verify` checks the signature for that principal — as Flux verifies a
source before it applies it.
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

from reconciler.base.errors import TrustError

SSH_SIGNATURE = b"-----BEGIN SSH SIGNATURE-----"
TIMEOUT = 30.0


def verify(signature: bytes | None, payload: bytes, allowed_signers: Path, *,
           what: str) -> str:
    """The principal whose allowed key signed `payload`; TrustError saying why not."""
    hint = f"sign it with a key listed in {allowed_signers} (git commit -S, gpg.format=ssh)"
    if not signature:
        raise TrustError(f"{what} is not signed", hint=hint)
    if not signature.startswith(SSH_SIGNATURE):
        raise TrustError(f"{what} is signed, but not with an SSH key (GPG?)", hint=hint)
    if not allowed_signers.is_file():
        raise TrustError(f"the allowed signers file {allowed_signers} does not exist",
                         hint="write it (OpenSSH allowed_signers format) or drop `trust:`")
    with tempfile.TemporaryDirectory(prefix="lpam-sig-") as tmp:
        sig = Path(tmp) / "commit.sig"
        sig.write_bytes(signature)
        found = _ssh_keygen(["-Y", "find-principals", "-s", str(sig),
                             "-f", str(allowed_signers)], b"")
        principals = found.stdout.decode("utf-8", "replace").split() \
            if found.returncode == 0 else []
        if not principals:
            raise TrustError(f"{what} is signed by a key not in {allowed_signers}", hint=hint)
        for principal in principals:
            checked = _ssh_keygen(["-Y", "verify", "-f", str(allowed_signers), "-I",
                                   principal, "-n", "git", "-s", str(sig)], payload)
            if checked.returncode == 0:
                return principal
    raise TrustError(f"{what}: its signature does not verify (the commit was altered after "
                     "it was signed?)", hint=hint)


def _ssh_keygen(args: list[str], stdin: bytes) -> subprocess.CompletedProcess[bytes]:
    try:
        return subprocess.run(["ssh-keygen", *args], input=stdin, capture_output=True,
                              timeout=TIMEOUT, check=False)
    except FileNotFoundError:
        raise TrustError("ssh-keygen is not installed: signatures cannot be checked",
                         hint="install OpenSSH's client (Debian: openssh-client)") from None
