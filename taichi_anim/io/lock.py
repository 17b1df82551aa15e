"""One run per output folder: an advisory lock (`flock(2)`) on a hidden file in the folder, held for the
whole run, so a second run into a busy folder stops before it removes or writes anything.

The lock file (`.taichi-anim.lock`, or `.clip.mp4.taichi-anim.lock` beside a video `clip.mp4` written
outside the run folder) holds the owner's process id, so the refusal can say which run is there. A run
killed even by SIGKILL leaves the file behind, but the kernel releases a `flock` when its holder dies,
so the next run finds the file unlocked and takes it over: a stale lock never blocks. The holder removes
the file when it is done. The lock is advisory (like Git's `index.lock` or a database's lock file, it
only keeps out other taichi_anim runs) and local: `flock` on network file systems (NFS, SMB) may not
reach other machines. Windows has no `fcntl`: there the lock is skipped.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import time
from collections.abc import Iterator
from pathlib import Path

from ..errors import FolderBusyError, OutputError
from .atomic import output_error

LOCK_NAME = ".taichi-anim.lock"
# A probe (check_not_busy) holds a lock for microseconds: a run that meets one retries for this long.
_RETRY_S = 0.25


def lock_path_for(target: str | os.PathLike) -> Path:
    """The lock file of a single file `target` (a video written outside the run folder):
    `.NAME.taichi-anim.lock` beside it, NAME its file name. A run folder's is `folder / LOCK_NAME`."""
    target = Path(target)
    return target.parent / f".{target.name}{LOCK_NAME}"


@contextlib.contextmanager
def hold_lock(lock: str | os.PathLike, *, what: str) -> Iterator[Path]:
    """Hold the exclusive lock `lock` (created if missing, removed when released) for the block; raise
    FolderBusyError naming `what` and the holder's PID if another process holds it."""
    try:
        import fcntl
    except ImportError:  # Windows
        yield Path(lock)
        return
    lock = Path(lock)
    fd = _acquire(lock, what, fcntl)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield lock
    finally:
        # Unlink while still holding the lock: a run that opened the old file before the unlink gets the
        # lock on a nameless inode and then sees (in _acquire) that the name no longer leads to it.
        with contextlib.suppress(OSError):
            if _same_file(fd, lock):
                lock.unlink()
        os.close(fd)


def check_not_busy(lock: str | os.PathLike, *, what: str) -> None:
    """Raise FolderBusyError if another process holds `lock`; creates nothing (for the command line, to
    refuse at once rather than after the scene compiled)."""
    try:
        import fcntl
    except ImportError:
        return
    lock = Path(lock)
    try:
        fd = _open(lock, create=False)
    except FileNotFoundError:
        return
    except OSError as e:
        raise _lock_error(lock, e) from e
    try:
        if _try_lock(fd, fcntl):
            fcntl.flock(fd, fcntl.LOCK_UN)
        else:
            raise _busy(lock, fd, what)
    finally:
        os.close(fd)


def _acquire(lock: Path, what: str, fcntl) -> int:
    deadline = time.monotonic() + _RETRY_S
    while True:
        try:
            fd = _open(lock, create=True)
        except OSError as e:
            raise _lock_error(lock, e) from e
        if _try_lock(fd, fcntl):
            if _same_file(fd, lock):
                return fd
            os.close(fd)  # its holder removed the file after we opened it: open the new one
            continue
        if time.monotonic() >= deadline:
            try:
                raise _busy(lock, fd, what)
            finally:
                os.close(fd)
        os.close(fd)
        time.sleep(0.02)


def _open(lock: Path, *, create: bool) -> int:
    # O_NOFOLLOW and O_NONBLOCK: a symbolic link or a FIFO planted under the lock's name must neither
    # redirect the lock elsewhere nor block the open.
    flags = os.O_RDWR | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    fd = os.open(lock, flags | (os.O_CREAT if create else 0), 0o644)
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise OSError(errno.EINVAL, "not a regular file", str(lock))
    return fd


def _try_lock(fd: int, fcntl) -> bool:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _same_file(fd: int, path: Path) -> bool:
    try:
        st = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    mine = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (mine.st_dev, mine.st_ino)


def _busy(lock: Path, fd: int, what: str) -> FolderBusyError:
    pid = _holder_pid(fd)
    who = f"process {pid}" if pid is not None else "a process whose id could not be read"
    return FolderBusyError(
        f"{what} is in use by another taichi-anim run ({who}; lock file {lock}): wait for it to finish, "
        "or choose another output",
        path=lock,
        pid=pid,
    )


def _holder_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _lock_error(lock: Path, e: OSError) -> OutputError:
    if e.errno in (errno.ELOOP, errno.EINVAL, errno.ENXIO, errno.EISDIR):
        return OutputError(
            f"cannot lock {lock.parent}: {lock} is not a regular file (a symbolic link, folder, FIFO or "
            "device); remove it"
        )
    return output_error(lock, e)
