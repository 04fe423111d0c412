"""A trial of a learned (or greedy) crowd, two ways: the torch trial loop (:mod:`~pedrl.trial.rollout`, the reference
and the GPU path) and the fused trial (:mod:`~pedrl.trial.fused`, one compiled pass per learning process on the CPU,
composed of the stage kernels in :mod:`pedrl.sim`, :mod:`pedrl.vq` and :mod:`pedrl.rl`), with what a trial reports
(:mod:`~pedrl.trial.stats`) and the harness that holds the two paths together (:mod:`~pedrl.trial.twins`).

The trainers (:mod:`pedrl.algos`) and the evaluation (:mod:`pedrl.evaluation`) both run trials through here; nothing
here imports a trainer.
"""
