"""The paper's trainers: VQQL, IT-VQQL and IN-VQQL, sharing :class:`pedrl.algos.base.Trainer`."""

from pedrl.algos.base import Phase, Trainer, TrainResult, VQSettings
from pedrl.algos.in_vqql import INVQQL, replicate_tables
from pedrl.algos.it_vqql import ITVQQL
from pedrl.algos.vqql import VQQL

__all__ = ["INVQQL", "ITVQQL", "VQQL", "Phase", "TrainResult", "Trainer", "VQSettings", "replicate_tables"]
