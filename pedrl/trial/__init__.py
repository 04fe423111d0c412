"""A trial of a learned (or greedy) crowd, two ways: the torch crowd loop (:mod:`~pedrl.trial.loop`, the reference
and the GPU path) and the fused trial (:mod:`~pedrl.trial.fused`, one compiled pass per learning process on the CPU,
composed of the stage kernels in :mod:`pedrl.sim`, :mod:`pedrl.vq` and :mod:`pedrl.rl`), chosen in one place
(:mod:`~pedrl.trial.crowd`), with what a trial reports (:mod:`~pedrl.trial.stats`), the trainers' rollouts
(:mod:`~pedrl.trial.rollout`) and the harness that holds the two paths together (:mod:`~pedrl.trial.twins`).

The trainers (:mod:`pedrl.algos`), the evaluation (:mod:`pedrl.evaluation`) and the validation suite
(:mod:`pedrl.validation`) all run trials through :func:`pedrl.trial.crowd.run_crowd`; nothing here imports a
trainer.
"""
