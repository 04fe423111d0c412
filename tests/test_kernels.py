"""The numba kernels (pedrl.sim.motion.*_kernel, pedrl.rl.kernels, pedrl.vq.tree) are compiled once per process: trials
of other sizes (agents, rooms, prototypes) reuse the same machine code, as torch.compile graphs must not be
recompiled per trial (issue 10)."""

import functools

import pytest
import torch

from pedrl._numba import numba_available
from pedrl.algos import VQQL, RunSpec
from pedrl.rl import kernels as rl_kernels
from pedrl.rl import zeros_q_values
from pedrl.scenarios import paper_room
from pedrl.sim.motion import sequential_kernel
from pedrl.trial import fused_kernels
from pedrl.vq import tree

pytestmark = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")

KERNELS = {
    False: {  # the torch trial loop's dispatchers
        "sequential rule": sequential_kernel._sequential,
        "greedy": rl_kernels._greedy,
        "TD update": rl_kernels.td_batch,
        "row prefetch": rl_kernels._prefetch,
        "tree search": tree._search,
        "tree construction": tree._build_tree,
    },
    True: {  # the fused trial (gathering, before it, steps the torch room)
        "sequential rule": sequential_kernel._sequential,
        "fused trial": fused_kernels.fused_trial,
        "tree construction": tree._build_tree,
    },
}


def run_trials(num_agents: int, prototypes: int, rooms_per_process: int, fused: bool) -> None:
    run = RunSpec(
        env=functools.partial(paper_room(width=12.0, length=12.0, door_width=3.0).room, max_decisions=40),
        vq={"num_prototypes": prototypes, "max_iterations": 2},
        processes=2,
        rooms_per_process=rooms_per_process,
        progress=False,
        tensorboard=False,
        fused=fused,
    )
    trainer = VQQL(run, num_agents=num_agents, trials=1, gather_trials=2)
    env = trainer.env_for(num_agents)
    env.reset(seed=num_agents)
    phase = trainer.phases()[0]
    quantizer, _ = trainer.fit_quantizers(phase, trainer.gather(phase, env, None), None)
    q_values = zeros_q_values(2, num_agents, quantizer.num_prototypes, env.num_actions, device="cpu")
    for _ in range(2):
        stats = trainer.run_trial(env, quantizer, q_values, epsilon=0.3, learn=True)
        assert stats.agent_decisions > 0


@pytest.mark.parametrize("fused", [False, True])
def test_each_kernel_is_compiled_once_for_trials_of_any_size(fused):
    """Whatever ran before (the test holds in any order): the trials of one size compile each kernel of their path,
    and trials of other sizes add no signature."""
    kernels = KERNELS[fused]
    run_trials(num_agents=6, prototypes=256, rooms_per_process=1, fused=fused)
    first = {name: len(kernel.signatures) for name, kernel in kernels.items()}
    assert min(first.values()) >= 1, first  # every kernel of the path ran
    run_trials(num_agents=9, prototypes=300, rooms_per_process=2, fused=fused)
    assert {name: len(kernel.signatures) for name, kernel in kernels.items()} == first


def test_numba_can_be_switched_off_for_the_torch_code(tmp_path):
    """PEDRL_NO_NUMBA=1 runs the torch code on the CPU: a seeded run of the torch trial loop (fused=False) gives the
    same numbers either way (its kernels are exact; the tree can differ from the matrix search only at float32 ties,
    which this run has none of). The fused trial is held to it within tolerances instead (tests/trial/test_fused.py)."""
    import json
    import os
    import subprocess
    import sys

    script = (
        "import functools, json, torch\n"
        "from pedrl.algos import VQQL, RunSpec\n"
        "from pedrl.scenarios import paper_room\n"
        "room = paper_room(width=12.0, length=12.0, door_width=3.0).room\n"
        "run = RunSpec(env=functools.partial(room, max_decisions=40), vq={'num_prototypes': 256, 'max_iterations': 2},"
        " processes=2, progress=False, tensorboard=False, seed=3, fused=False)\n"
        "t = VQQL(run, num_agents=6, trials=6, gather_trials=2)\n"
        "r = t.fit()\n"
        "print(json.dumps(r.final))\n"
    )
    finals = []
    for value in ("0", "1"):
        env = {**os.environ, "PEDRL_NO_NUMBA": value}
        output = subprocess.run(
            [sys.executable, "-c", script], env=env, cwd=tmp_path, capture_output=True, text=True, check=True
        )
        finals.append(json.loads(output.stdout.strip().splitlines()[-1]))
    assert finals[0] == finals[1]
    assert torch.tensor(finals[0]["success_rate_mean"]).isfinite()
