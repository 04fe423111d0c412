"""Input and output: checkpoints and run logging."""

from pedrl.io.checkpoint import Checkpoint, CheckpointError, load_checkpoint, save_checkpoint
from pedrl.io.metrics import CsvWriter, RunLogger, read_csv

__all__ = [
    "Checkpoint",
    "CheckpointError",
    "CsvWriter",
    "RunLogger",
    "load_checkpoint",
    "read_csv",
    "save_checkpoint",
]
