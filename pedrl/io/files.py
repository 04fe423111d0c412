"""Atomic file replacement, shared by checkpoints and the learning-curve rewrite.

A file is replaced by writing a temporary sibling ``.<name>.<random>.tmp`` in the same folder, fsyncing it and
renaming it over the destination (``os.replace``, atomic on POSIX). A process killed at any moment leaves either
the old file or the new one; a temporary it leaves behind is removed by the next write of the same file.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable, Iterable
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
    except OSError as err:
        temporary.unlink(missing_ok=True)
        raise named(err, path) from err
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    fsync_folder(path.parent)
    return path


def named(err: OSError, path: str | os.PathLike) -> OSError:
    """``err`` if it names a file, else the same error naming ``path`` (a full disk fails at a write or ``close``
    that names no file): the message a user sees then says which file could not be written."""
    if err.filename is not None:
        return err
    return OSError(err.errno, err.strerror or str(err), str(path)) if err.errno is not None else err


def fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def output_problem(
    path: str | os.PathLike, *, folder: bool = False, probed: dict[Path, str | None] | None = None
) -> str | None:
    """Why ``path`` cannot be written as an output ``folder`` (or file), in one line naming it; None when it can.

    A folder must be a folder (or not exist yet), a file must not be a folder; every existing part of the path above
    it must be a folder, and the nearest existing one must take a new file: a file is written into it and removed
    again (permission bits alone do not tell: root ignores them, a read-only mount does not show in them). Nothing
    else is created. ``probed`` caches the probe per folder across calls.
    """
    path = Path(path)
    kind = "folder" if folder else "file"
    allowed = "must be a folder this user can write in" if folder else "must be a file this user can write, or absent"
    where = f"output {kind} {str(path)!r} is invalid"
    if folder and path.exists() and not path.is_dir():
        return f"{where}: it is a file; {allowed}"
    if not folder and path.is_dir():
        return f"{where}: it is a folder; {allowed}"
    existing = path if folder and path.is_dir() else path.parent
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        return f"{where}: {str(existing)!r} is a file, not a folder; {allowed}"
    cache = probed if probed is not None else {}
    if existing not in cache:
        cache[existing] = _write_probe(existing)
    reason = cache[existing]
    if reason is not None:
        return (
            f"{where}: {'it' if existing == path else repr(str(existing))} cannot be written in ({reason}); {allowed}"
        )
    return None


def _write_probe(folder: Path) -> str | None:
    """Why a file cannot be created in ``folder``, or None when one can (it is created and removed again)."""
    import tempfile

    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        return err.strerror or type(err).__name__
    return None


def check_outputs(folders: Iterable[str | os.PathLike] = (), files: Iterable[str | os.PathLike] = ()) -> None:
    """Raise a one-line ``ValueError`` naming the first output folder or file that cannot be written
    (:func:`output_problem`): called before any compute, so that a bad path costs no run and leaves no half-written
    output behind."""
    probed: dict[Path, str | None] = {}
    for paths, folder in ((folders, True), (files, False)):
        for path in paths:
            problem = output_problem(path, folder=folder, probed=probed)
            if problem is not None:
                raise ValueError(problem)
