"""A lock on an output that a run reads, changes and writes back (the output .blend a retarget adds to).

Two runs adding to one .blend at once would each read it, add their action and rename their copy into
place: the last rename wins and the other action is lost. ``output_lock`` makes the second run wait
(with a message naming the holder) until the first has written the file, so it then reads the file
with the first run's action in it.

The lock is an advisory lock (``flock``; ``msvcrt.locking`` on Windows) on a small file beside the
output, ``.<name>.facecap-lock``. The operating system releases it when the holder ends, however it
ends (SIGKILL, a crash), so a lock is never left held; on NFS it works across the machines of a farm
(Linux maps ``flock`` onto NFS byte-range locks). The holder writes its host and pid into the file for
the waiting message, and removes the file when it is done (a waiter that locked a removed file tries
again on the new one).
"""

import contextlib
import os
import socket
import time
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None
    import msvcrt

from .files import umask

LOCK_SUFFIX = ".facecap-lock"
#: Seconds between two attempts while waiting, and between two reminders that the run still waits.
POLL_SECONDS = 0.2
REMIND_SECONDS = 60.0


def lock_path(path):
    """The lock file of output ``path``."""
    path = Path(path)
    return path.parent / f".{path.name}{LOCK_SUFFIX}"


@contextlib.contextmanager
def output_lock(path, *, say=None, timeout=None):
    """Hold the lock of output ``path`` for the block (see the module docstring).

    say : callable(str) or None
        Told once that the run waits, whom for, and every ``REMIND_SECONDS`` after.
    timeout : float or None
        Seconds to wait at most (None: until the holder is done; Ctrl-C stops the wait).

    Raises
    ------
    TimeoutError when ``timeout`` passes first.
    """
    target = lock_path(path)
    made = []
    start = time.monotonic()
    reminded = None
    while True:
        made += _make_folders(target.parent)  # (again if a holder that wrote nothing removed them)
        try:
            fd = os.open(target, os.O_RDWR | os.O_CREAT, 0o666 & ~umask())
        except FileNotFoundError:
            continue
        if _try_lock(fd):
            if _same_file(fd, target):
                break
            _unlock(fd)  # the holder removed this file after we opened it: lock the new one
            os.close(fd)
            continue
        holder = _holder(fd)
        os.close(fd)
        now = time.monotonic()
        if timeout is not None and now - start >= timeout:
            raise TimeoutError(f"{Path(path)}: {holder} has been writing it for more than {timeout:g} s")
        if say is not None and (reminded is None or now - reminded >= REMIND_SECONDS):
            say(f"waiting for {holder} to finish writing {Path(path)}")
            reminded = now
        time.sleep(POLL_SECONDS)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{socket.gethostname()} {os.getpid()} {time.time():.0f}\n".encode())
        yield target
    finally:
        with contextlib.suppress(OSError):
            target.unlink()  # while still held: a waiter then sees it gone and locks a new file
        _unlock(fd)
        os.close(fd)
        for folder in made:  # the folders made for the lock, if the run wrote nothing into them
            with contextlib.suppress(OSError):
                folder.rmdir()


def _make_folders(folder):
    """Make ``folder`` and its missing parents; returns those made, deepest first."""
    made = []
    while not folder.exists() and folder != folder.parent:
        made.append(folder)
        folder = folder.parent
    for f in reversed(made):
        with contextlib.suppress(FileExistsError):
            f.mkdir()
    return made


def _try_lock(fd):
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        else:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
    except OSError:  # held by another process (BlockingIOError, or EACCES / EDEADLK on some systems)
        return False
    return True


def _unlock(fd):
    with contextlib.suppress(OSError):
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_UN)
        else:
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)


def _same_file(fd, target):
    try:
        a, b = os.fstat(fd), os.stat(target)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _holder(fd):
    """'another facecap run (host H, pid P)' from what the holder wrote into the lock file."""
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        words = os.read(fd, 200).decode("utf-8", "replace").split()
    except OSError:
        words = []
    if len(words) >= 2:
        return f"another facecap run (host {words[0]}, pid {words[1]})"
    return "another facecap run"
