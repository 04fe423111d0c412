"""Atomic file replacement, shared by checkpoints and the learning-curve rewrite.

A file is replaced by writing a temporary sibling ``.<name>.<random>.tmp`` in the same folder, fsyncing it and
renaming it over the destination (``os.replace``, atomic on POSIX). A process killed at any moment leaves either
the old file or the new one; a temporary it leaves behind is removed by the next write of the same file.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path

FILE_MODE = 0o666
"""Mode of new files before the umask, as ``open`` creates them (0644 under the usual umask 022)."""


def temporary_sibling(path: Path) -> Path:
    """A new, empty temporary file next to ``path`` (mode 0666 less the umask, like any file ``open`` makes)."""
    while True:
        candidate = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
        try:
            fd = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL, FILE_MODE)
        except FileExistsError:
            continue
        os.close(fd)
        return candidate


def remove_temporaries(path: Path) -> list[Path]:
    """Delete the temporaries of ``path`` left by a process killed while replacing it; returns them."""
    stale = sorted(path.parent.glob(f".{path.name}.*.tmp")) if path.parent.is_dir() else []
    for leftover in stale:
        leftover.unlink(missing_ok=True)
    return stale


def remove_temporaries_in(folder: Path) -> list[Path]:
    """Delete every temporary (``.<name>.<random>.tmp``) left in ``folder`` by a killed process; returns them."""
    stale = sorted(folder.glob(".*.*.tmp")) if folder.is_dir() else []
    for leftover in stale:
        leftover.unlink(missing_ok=True)
    return stale


def replace_atomically(path: str | os.PathLike, write: Callable[[Path], None]) -> Path:
    """Replace ``path`` by what ``write(temporary_path)`` writes, atomically; parent folders are created.

    Leftover temporaries of ``path`` are removed first. On any error (or interruption) the temporary is removed
    and ``path`` is unchanged.

    Returns:
        The destination path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_temporaries(path)
    temporary = temporary_sibling(path)
    mode = temporary.stat().st_mode & 0o777  # 0666 less the umask
    try:
        write(temporary)
        os.chmod(temporary, mode)  # some writers (safetensors) recreate the file 0600
        with open(temporary, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    fsync_folder(path.parent)
    return path


def fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
