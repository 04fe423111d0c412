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
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

import pedrl

FORMAT_NAME: Final = "pedrl-checkpoint"
FORMAT_VERSION: Final = 1
METADATA_KEY: Final = "pedrl"


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: missing, corrupt, truncated, foreign or incompatible."""


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

    A process killed at any moment leaves either the previous file or the new one, never a broken one.

    Args:
        path: destination ``.safetensors`` path; parent folders are created.
        tensors: named tensors (any device; they are copied to CPU and made contiguous).
        metadata: JSON-serialisable dictionary stored under the ``pedrl`` metadata key.

    Returns:
        The destination path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "pedrl_version": pedrl.__version__,
        **metadata,
    }
    cpu_tensors = {name: t.detach().to("cpu").contiguous() for name, t in tensors.items()}
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        save_file(cpu_tensors, tmp_name, metadata={METADATA_KEY: json.dumps(header)})
        with open(tmp_name, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    return path


def load_checkpoint(path: str | os.PathLike, *, device: str | torch.device = "cpu") -> Checkpoint:
    """Read a checkpoint written by :func:`save_checkpoint`.

    Raises:
        CheckpointError: one line naming the path and the problem (missing, not a safetensors file,
            truncated or corrupt, not a pedrl checkpoint, or a newer format).
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {str(path)!r} does not exist (expected a .safetensors file)")
    try:
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as handle:
            raw = (handle.metadata() or {}).get(METADATA_KEY)
        tensors = load_file(str(path), device=str(device))
    except (SafetensorError, OSError, RuntimeError, ValueError) as err:
        first_line = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise CheckpointError(
            f"checkpoint {str(path)!r} is corrupt or truncated, or not a safetensors file ({first_line})"
        ) from None
    if raw is None:
        raise CheckpointError(f"checkpoint {str(path)!r} is a safetensors file but not a pedrl checkpoint")
    try:
        metadata = json.loads(raw)
    except json.JSONDecodeError:
        raise CheckpointError(f"checkpoint {str(path)!r} has unreadable pedrl metadata") from None
    if metadata.get("format") != FORMAT_NAME:
        raise CheckpointError(f"checkpoint {str(path)!r} is not a pedrl checkpoint (format={metadata.get('format')!r})")
    if int(metadata.get("format_version", -1)) > FORMAT_VERSION:
        raise CheckpointError(
            f"checkpoint {str(path)!r} has format_version={metadata['format_version']}, "
            f"this pedrl reads up to {FORMAT_VERSION}"
        )
    return Checkpoint(tensors=tensors, metadata=metadata, path=path)
