"""The learners, each on one learning run (:class:`pedrl.algos.run.LearningRun`, told what the run is by a
:class:`pedrl.algos.run.RunSpec`): the paper's trainers, VQQL, IT-VQQL and IN-VQQL, sharing
:class:`pedrl.algos.base.Trainer`; and the neural learners beside them, DQN (:mod:`pedrl.algos.dqn`) and
shared-parameter PPO (:mod:`pedrl.algos.ppo`)."""

from pedrl.algos.base import Trainer
from pedrl.algos.dqn import DQN
from pedrl.algos.in_vqql import INVQQL, replicate_tables
from pedrl.algos.it_vqql import ITVQQL
from pedrl.algos.phase import Phase, TrainResult
from pedrl.algos.ppo import PPO
from pedrl.algos.run import LearningRun, RunSpec
from pedrl.algos.vqql import VQQL
from pedrl.vq.settings import VQSettings

__all__ = [
    "DQN",
    "INVQQL",
    "ITVQQL",
    "PPO",
    "VQQL",
    "LearningRun",
    "Phase",
    "RunSpec",
    "TrainResult",
    "Trainer",
    "VQSettings",
    "replicate_tables",
]
