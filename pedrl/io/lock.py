"""One run per folder: an exclusive lock on ``<run folder>/.pedrl.lock`` while a training run writes there.

Two runs writing one folder would interleave their learning curves and checkpoints, and one run's results would be
lost. The lock is ``fcntl.flock`` on the lock file, which holds the holder's process id for the message of a second
run. The kernel releases a flock when its process ends, however it ends, so a run killed with ``SIGKILL`` leaves a
file but no lock: the next run takes it. A run that ends normally removes the file.
"""

from __future__ import annotations

import errno
import fcntl
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pedrl.io.files import FILE_MODE
from pedrl.notices import warn

__all__ = ["LOCK_NAME", "RunFolderInUseError", "run_folder_lock"]

LOCK_NAME = ".pedrl.lock"
"""Name of the lock file in the run folder."""
_UNSUPPORTED = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS)
"""``flock`` errors of file systems without locks (some network mounts): the run goes on unguarded."""
_PID_WAIT_S = 0.5
"""How long a refused run waits for the holder to write its process id (it does so right after locking)."""


class RunFolderInUseError(ValueError):
    """Another process holds the lock of the run folder (a one-line user error: ``pedrl-train`` exits with 2)."""


@contextmanager
def run_folder_lock(run_dir: str | os.PathLike) -> Iterator[Path]:
    """Hold the lock of ``run_dir`` (created if missing) for the duration of the ``with`` block.

    Raises:
        RunFolderInUseError: another process holds it; the message names the folder and that process's id.

    Yields:
        The lock file's path.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / LOCK_NAME
    fd = _acquire(path, run_dir)
    try:
        if fd is not None:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        yield path
    finally:
        if fd is not None:
            path.unlink(missing_ok=True)  # while locked: a run that opened it just before sees it gone, retries
            os.close(fd)  # releases the lock


def _acquire(path: Path, run_dir: Path) -> int | None:
    """The descriptor of ``path``, locked; None where the file system has no locks."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, FILE_MODE)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise RunFolderInUseError(
                f"run folder {str(run_dir)!r} is in use by another pedrl-train ({holder}): one run per folder; "
                "wait for it to end, or pass another hydra.run.dir"
            ) from None
        except OSError as err:
            os.close(fd)
            if err.errno not in _UNSUPPORTED:
                raise
            warn(f"run folder {str(run_dir)!r} cannot be locked ({err.strerror}): a second run there is not refused")
            return None
        try:
            same_file = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same_file = False
        if same_file:
            return fd
        os.close(fd)  # locked a file its holder removed on leaving: lock the current one


def _holder(fd: int) -> str:
    """``pid N`` of the process that holds the lock of ``fd``, as it writes it just after locking (waited for up to
    :data:`_PID_WAIT_S`)."""
    deadline = time.monotonic() + _PID_WAIT_S
    while True:
        text = os.pread(fd, 32, 0).decode("ascii", errors="replace").strip()
        if text.isdigit():
            return f"pid {text}"
        if time.monotonic() > deadline:
            return "process id unknown"
        time.sleep(0.01)
