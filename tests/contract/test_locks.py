"""Update locks against the real thing: util-linux `flock` processes started by the tests
(and stopped by their pid, whole process group, in a `finally`), real files under tmp_path,
the machine's own /proc/locks; and the /proc/locks parser against fixture text of the shapes
the kernel writes."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from reconciler.adapters.locks import (
    Busy,
    Holder,
    UpdateLocks,
    command_of,
    flock_holders,
    holders,
    parse_proc_locks,
    probe,
)
from reconciler.base.errors import LpamError

WAIT_SECONDS = 5.0


@contextmanager
def flock_held(path: Path) -> Iterator[subprocess.Popen[bytes]]:
    """An app holding `path` as `flock PATH -c 'sleep 30'` does, until the block ends.

    The flock process forks `sleep`, which inherits the locked descriptor: killing flock
    alone would leave the lock held, so the whole process group it leads is stopped."""
    proc = subprocess.Popen(["flock", str(path), "-c", "sleep 30"], start_new_session=True,
                            stdin=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + WAIT_SECONDS
        while not holders(path):
            assert proc.poll() is None, "flock ended before taking the lock"
            assert time.monotonic() < deadline, "flock did not take the lock in time"
            time.sleep(0.01)
        yield proc
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        # The group's sleep may outlive flock's wait() by a moment; it is the last holder.
        deadline = time.monotonic() + WAIT_SECONDS
        while holders(path) and time.monotonic() < deadline:
            time.sleep(0.01)


def flock_n(path: Path) -> int:
    """The exit code of another process trying the lock now: 0 taken, 1 held elsewhere."""
    return subprocess.run(["flock", "-n", str(path), "true"], check=False).returncode


# --- flock locks -----------------------------------------------------------------------

def test_an_app_holding_the_lock_is_named_then_free_once_it_ends(tmp_path: Path) -> None:
    lock = tmp_path / "locks" / "recording.lock"
    lock.parent.mkdir()
    with flock_held(lock) as app:
        busy = probe([(lock, False)])
        assert busy == [Busy(lock, (Holder(app.pid, f"flock {lock} -c sleep 30"),), False)]
        assert busy[0].describe() == (
            f"{lock} is held by pid {app.pid} (flock {lock} -c sleep 30)")
    assert probe([(lock, False)]) == []


def test_lpam_keeps_the_locks_until_released(tmp_path: Path) -> None:
    first, second = tmp_path / "a.lock", tmp_path / "b.lock"
    with UpdateLocks() as locks:
        assert locks.take([(first, False), (second, False)]) == []
        assert locks.held == (first, second)
        assert flock_n(first) == flock_n(second) == 1  # no critical section can begin
        held_by_us = holders(first)
        assert [h.pid for h in held_by_us] == [os.getpid()]
    assert flock_n(first) == flock_n(second) == 0
    assert holders(first) == ()


def test_release_lets_go_and_the_locks_can_be_taken_again(tmp_path: Path) -> None:
    lock = tmp_path / "recording.lock"
    locks = UpdateLocks()
    assert locks.take([(lock, False)]) == []
    assert flock_n(lock) == 1
    locks.release()
    assert flock_n(lock) == 0
    assert locks.take([(lock, False)]) == []
    locks.release()
    locks.release()  # twice is harmless


def test_one_busy_lock_means_none_is_kept(tmp_path: Path) -> None:
    free, taken = tmp_path / "free.lock", tmp_path / "taken.lock"
    with flock_held(taken) as app, UpdateLocks() as locks:
        busy = locks.take([(free, False), (taken, False)])
        assert [(b.path, [h.pid for h in b.holders]) for b in busy] == [(taken, [app.pid])]
        assert locks.held == ()
        assert flock_n(free) == 0  # taken first, then given back


def test_a_missing_lock_file_is_free_and_created_with_its_folders(tmp_path: Path) -> None:
    lock = tmp_path / "run" / "lpam" / "locks" / "recording.lock"
    assert probe([(lock, False)]) == []
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(lock.stat().st_mode) == 0o644 & ~umask
    assert lock.read_bytes() == b""


def test_the_same_lock_named_twice_is_one_lock(tmp_path: Path) -> None:
    lock = tmp_path / "recording.lock"
    assert probe([(lock, False), (lock, False)]) == []


# --- persistent locks ------------------------------------------------------------------

def test_a_persistent_lock_is_held_while_its_file_exists(tmp_path: Path) -> None:
    lock = tmp_path / "data" / "experiment.lock"
    assert probe([(lock, True)]) == []
    assert not lock.parent.exists()  # lpam never creates a persistent lock or its folder
    lock.parent.mkdir()
    lock.write_text("calibrating\n")
    busy = probe([(lock, True)])
    assert busy == [Busy(lock, (), True)]
    assert busy[0].describe() == (
        f"{lock} exists (a persistent lock; remove it to allow updates)")
    lock.unlink()
    assert probe([(lock, True)]) == []


def test_every_busy_lock_is_reported(tmp_path: Path) -> None:
    held, kept = tmp_path / "recording.lock", tmp_path / "experiment.lock"
    kept.touch()
    with flock_held(held):
        busy = probe([(held, False), (kept, True)])
    assert [(b.path, b.persistent) for b in busy] == [(held, False), (kept, True)]


# --- what lpam refuses -----------------------------------------------------------------

@pytest.mark.parametrize("persistent", [False, True])
def test_a_symbolic_link_is_refused_and_not_followed(tmp_path: Path, persistent: bool) -> None:
    target = tmp_path / "elsewhere"
    lock = tmp_path / "recording.lock"
    lock.symlink_to(target)  # dangling: following it would create `elsewhere`
    with pytest.raises(LpamError) as caught:
        probe([(lock, persistent)])
    assert "symbolic link" in caught.value.message and caught.value.hint
    assert not target.exists()
    target.touch()
    with pytest.raises(LpamError):
        probe([(lock, persistent)])


@pytest.mark.parametrize("persistent", [False, True])
def test_a_directory_is_refused(tmp_path: Path, persistent: bool) -> None:
    lock = tmp_path / "recording.lock"
    lock.mkdir()
    with pytest.raises(LpamError) as caught:
        probe([(lock, persistent)])
    assert "directory" in caught.value.message and caught.value.hint


def test_a_refusal_lets_go_of_the_locks_already_taken(tmp_path: Path) -> None:
    good, bad = tmp_path / "good.lock", tmp_path / "bad.lock"
    bad.mkdir()
    locks = UpdateLocks()
    with pytest.raises(LpamError):
        locks.take([(good, False), (bad, False)])
    assert locks.held == () and flock_n(good) == 0


@pytest.mark.parametrize("persistent", [False, True])
def test_a_lock_under_a_file_is_refused(tmp_path: Path, persistent: bool) -> None:
    (tmp_path / "locks").touch()
    with pytest.raises(LpamError, match="cannot use the update lock"):
        probe([(tmp_path / "locks" / "recording.lock", persistent)])


def test_a_fifo_does_not_hang_lpam(tmp_path: Path) -> None:
    lock = tmp_path / "recording.lock"
    os.mkfifo(lock)
    with pytest.raises(LpamError, match="not a plain file"):
        probe([(lock, False)])


# --- who holds it: /proc/locks ---------------------------------------------------------

# Shapes the kernel writes (fs/locks.c, lock_get_status): waiters under their blocker with
# "->", POSIX/OFD/lease lines, devices in hex with two or more digits, `<none>` for a lock
# without an inode, and pid -1 for an OFD lock.
PROC_LOCKS = """\
1: FLOCK  ADVISORY  WRITE 4242 b3:02:131091 0 EOF
1: -> FLOCK  ADVISORY  WRITE 4250 b3:02:131091 0 EOF
2: POSIX  ADVISORY  WRITE 812 b3:02:131091 0 EOF
3: OFDLCK ADVISORY  READ  -1 00:2f:9 0 EOF
4: FLOCK  ADVISORY  READ  900 00:2f:131091 0 EOF
5: FLOCK  ADVISORY  READ  901 103:0a:77 0 EOF
5: FLOCK  ADVISORY  READ  902 103:0a:77 0 EOF
5: FLOCK  ADVISORY  READ  902 103:0a:77 0 EOF
6: LEASE  ACTIVE    READ  1200 fe:00:2482914 0 EOF
7: POSIX  ADVISORY  WRITE 33 <none>:0 0 EOF
"""


def test_proc_locks_lines_are_parsed() -> None:
    lines = parse_proc_locks(PROC_LOCKS)
    assert len(lines) == 9  # the <none> line names no file
    first, waiter = lines[0], lines[1]
    assert (first.kind, first.access, first.pid, first.major, first.minor, first.inode,
            first.waiting) == ("FLOCK", "WRITE", 4242, 0xB3, 2, 131091, False)
    assert waiter.pid == 4250 and waiter.waiting
    assert lines[3].pid == -1 and lines[3].kind == "OFDLCK"
    assert (lines[5].major, lines[5].minor) == (259, 10)
    assert parse_proc_locks("") == [] and parse_proc_locks("garbage\n\n") == []


def test_only_flock_holders_of_that_very_file_count() -> None:
    # Not the waiter, not the POSIX lock on the same file, not the same inode elsewhere.
    assert flock_holders(PROC_LOCKS, major=0xB3, minor=2, inode=131091) == (4242,)
    assert flock_holders(PROC_LOCKS, major=0, minor=0x2F, inode=131091) == (900,)
    assert flock_holders(PROC_LOCKS, major=259, minor=10, inode=77) == (901, 902)  # shared
    assert flock_holders(PROC_LOCKS, major=0xB3, minor=2, inode=131092) == ()
    assert flock_holders(PROC_LOCKS, major=0xB3, minor=3, inode=131091) == ()


def fake_proc(tmp_path: Path, locks: str, commands: dict[int, bytes]) -> Path:
    proc = tmp_path / "proc"
    proc.mkdir()
    (proc / "locks").write_text(locks)
    for pid, cmdline in commands.items():
        (proc / str(pid)).mkdir()
        (proc / str(pid) / "cmdline").write_bytes(cmdline)
    return proc


def test_holders_match_the_file_and_read_each_command(tmp_path: Path) -> None:
    lock = tmp_path / "recording.lock"
    lock.touch()
    st = lock.stat()
    where = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    proc = fake_proc(tmp_path, f"""\
1: FLOCK  ADVISORY  WRITE 4242 {where} 0 EOF
2: FLOCK  ADVISORY  WRITE 4243 {where}0 0 EOF
3: FLOCK  ADVISORY  READ  4244 {where} 0 EOF
""", {4242: b"flock\0/run/lpam/locks/recording.lock\0-c\0record.sh\0", 4244: b""})
    assert holders(lock, proc=proc) == (
        Holder(4242, "flock /run/lpam/locks/recording.lock -c record.sh"),
        Holder(4244, "?"),  # a zombie has an empty command line
    )
    assert holders(tmp_path / "missing.lock", proc=proc) == ()


def test_a_process_that_cannot_be_read_is_a_question_mark(tmp_path: Path) -> None:
    proc = fake_proc(tmp_path, "", {7: b"record\0--bag\0\x1b[31m\0"})
    assert command_of(99, proc=proc) == "?"  # gone
    assert command_of(0, proc=proc) == "?"
    assert command_of(7, proc=proc) == "record --bag ?[31m"  # no terminal escapes
    assert holders(tmp_path / "x", proc=tmp_path / "noproc") == ()
    assert Busy(tmp_path / "x", (), False).describe().endswith("lpam cannot see "
                                                               "(not in /proc/locks, "
                                                               "perhaps in a container)")
