"""Checkpoints: safetensors files written atomically and read without executing code.

A checkpoint is one ``.safetensors`` file: named tensors (prototypes, standardisation statistics, Q tables,
generator states) plus string metadata. The metadata key ``pedrl`` holds one JSON document with the format
name and version, the package version, the resolved config, the algorithm, the iteration and any extra state
the trainer needs to resume. safetensors stores raw tensor bytes and a JSON header only, so loading a file can
never run code from it (unlike ``torch.load`` of a pickle).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from pedrl.common.checks import first_line
from pedrl.io.files import replace_atomically
from pedrl.version import __version__

FORMAT_NAME: Final = "pedrl-checkpoint"
FORMAT_VERSION: Final = 1
METADATA_KEY: Final = "pedrl"


class CheckpointError(ValueError):
    """A checkpoint that cannot be used (missing, corrupt, truncated, foreign or incompatible) or written."""


@dataclass(frozen=True)
class Checkpoint:
    """A loaded checkpoint.

    Attributes:
        tensors: named tensors, on the device asked for at load time.
        metadata: the decoded JSON metadata (``format``, ``format_version``, ``pedrl_version``, ``algo``,
            ``iteration``, ``config`` and trainer-specific entries).
        path: where it was read from.
    """

    tensors: dict[str, torch.Tensor]
    metadata: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    def tensors_with_prefix(self, prefix: str) -> dict[str, torch.Tensor]:
        """Tensors whose name starts with ``prefix + '/'``, with that prefix removed."""
        start = prefix + "/"
        return {name[len(start) :]: t for name, t in self.tensors.items() if name.startswith(start)}


def save_checkpoint(path: str | os.PathLike, *, tensors: dict[str, torch.Tensor], metadata: dict[str, Any]) -> Path:
    """Write a checkpoint atomically: temporary file in the same folder, fsync, then ``os.replace``.

    A process killed at any moment leaves either the previous file or the new one, never a broken one; the
    temporary it may leave behind (``.<name>.<random>.tmp``) is removed by the next save of the same file. The
    file gets the mode of any new file (0644 under the usual umask).

    Args:
        path: destination ``.safetensors`` path; parent folders are created.
        tensors: named tensors (any device; they are copied to CPU and made contiguous).
        metadata: JSON-serialisable dictionary stored under the ``pedrl`` metadata key.

    Returns:
        The destination path.

    Raises:
        CheckpointError: one line naming the path, when the file cannot be written (full disk, no permission);
            the previous file, if any, is left as it was.
    """
    path = Path(path)
    header = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "pedrl_version": __version__,
        **metadata,
    }
    cpu_tensors = {name: t.detach().to("cpu").contiguous() for name, t in tensors.items()}
    encoded = {METADATA_KEY: json.dumps(header)}
    try:
        return replace_atomically(path, lambda temporary: save_file(cpu_tensors, str(temporary), metadata=encoded))
    except (SafetensorError, OSError) as err:
        reason = err.strerror if isinstance(err, OSError) and err.strerror else first_line(err)
        raise CheckpointError(f"cannot write checkpoint {str(path)!r}: {reason}") from None


def _file_kind(path: Path) -> str:
    """What ``path`` is, when it is not a regular file: a FIFO, a device, a socket, or a link to one (or dangling)."""
    import stat

    try:
        mode = path.stat().st_mode
    except OSError:
        return "a dangling link"
    kinds = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
             (stat.S_ISSOCK, "a socket"))  # fmt: skip
    kind = next((name for test, name in kinds if test(mode)), "not a regular file")
    return f"a link to {kind}" if path.is_symlink() else kind


def load_checkpoint(path: str | os.PathLike, *, device: str | torch.device = "cpu") -> Checkpoint:
    """Read a checkpoint written by :func:`save_checkpoint`.

    Raises:
        CheckpointError: one line naming the path and the problem (missing, not a safetensors file,
            truncated or corrupt, not a pedrl checkpoint, or a newer format).
    """
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(f"checkpoint {str(path)!r} is a directory (expected a .safetensors file)")
    if not path.is_file():
        if not path.exists() and not path.is_symlink():
            raise CheckpointError(f"checkpoint {str(path)!r} does not exist (expected a .safetensors file)")
        kind = _file_kind(path)
        raise CheckpointError(f"checkpoint {str(path)!r} is {kind}: only regular files are read (a .safetensors file)")
    try:
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as handle:
            raw = (handle.metadata() or {}).get(METADATA_KEY)
        tensors = load_file(str(path), device=str(device))
    except (SafetensorError, OSError, RuntimeError, ValueError, OverflowError) as err:
        raise CheckpointError(
            f"checkpoint {str(path)!r} is corrupt or truncated, or not a safetensors file ({first_line(err)})"
        ) from None
    if raw is None:
        raise CheckpointError(f"checkpoint {str(path)!r} is a safetensors file but not a pedrl checkpoint")
    try:
        metadata = json.loads(raw)
    except (json.JSONDecodeError, RecursionError):
        raise CheckpointError(f"checkpoint {str(path)!r} has unreadable pedrl metadata") from None
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT_NAME:
        found = metadata.get("format") if isinstance(metadata, dict) else type(metadata).__name__
        raise CheckpointError(f"checkpoint {str(path)!r} is not a pedrl checkpoint (format={found!r})")
    version = metadata.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise CheckpointError(
            f"checkpoint {str(path)!r} has format_version={version!r}: must be an integer in [1, {FORMAT_VERSION}]"
        )
    if version > FORMAT_VERSION:
        raise CheckpointError(
            f"checkpoint {str(path)!r} has format_version={version}, this pedrl reads up to {FORMAT_VERSION}"
        )
    return Checkpoint(tensors=tensors, metadata=metadata, path=path)
