"""Who may write what lpam makes: its owner alone (root on a car), never its group or others.

Everything lpam keeps decides what runs as root: the desired state and the agent's
settings (which commits run), the state record and journal (what an apply resumes), the
repository store and the generations (the code itself), the apps' Python environments,
supervisord's configuration, the scripts' exit codes and lpam's logs (what an operator
trusts when deciding). Another user who could write any of them could make root run their
code, so lpam creates none of them writable by its group or by others, and `lpam status`
names any that has become so (reconciler/report/exposure.py).

Reading stays open (directories 0o755, files 0o644), a choice made per kind of file:
- the generations, `/etc/libpanda.d/apps` and the Python environments must be readable by
  an app that runs as its own user (`user:` in a catalog);
- the desired state, the state record, the store and the logs hold no secret lpam could
  keep: a token in a repository's URL is the operator's to protect in the desired state
  they wrote, whose mode lpam keeps when it edits it (less group and other write); and a
  log or record that only root could read would turn every look at a car into a `sudo`;
- what must stay private already is: supervisord's socket (0o700, its configuration), the
  lock files hold only a pid and a command.

The means is the umask: most of what lpam creates is made by code it does not write
(dulwich's object store, `python -m venv` and pip, supervisord's logs, the apps' own
install scripts), so a mode passed at each `mkdir` could not reach it. A user's login may
hand lpam a umask of 002 (or `sudo` may keep one): lpam adds 022 to whatever it was given,
never loosens it.
"""

from __future__ import annotations

import os
import stat

SHARED_WRITE = stat.S_IWGRP | stat.S_IWOTH
"""The bits lpam never sets: write by the file's group, write by others."""


def keep_writes_private() -> None:
    """Make everything this process and its children create unwritable by group and
    others (the umask gains 022; a stricter one is kept). Called first by every face."""
    given = os.umask(SHARED_WRITE)
    os.umask(given | SHARED_WRITE)


def private(mode: int) -> int:
    """`mode` without group and other write: what lpam writes, whatever mode it keeps."""
    return mode & ~SHARED_WRITE
