"""The same answers on CUDA (skipped without a GPU)."""

import pytest
import torch

from pedrl.rl import epsilon_greedy, td_update, zeros_q_values
from pedrl.scenarios import paper_room
from pedrl.vq import Quantizer, UnionQuantizer
from pedrl.vq.kmeans import kmeans, nearest_prototype

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


def test_nearest_prototype_and_kmeans_on_cuda():
    generator = torch.Generator().manual_seed(0)
    points = torch.randn(3000, 28, generator=generator)
    prototypes = torch.randn(600, 28, generator=generator)
    ids_cpu, _ = nearest_prototype(points, prototypes, precision="float32")
    ids_cuda, sq_dist = nearest_prototype(points.cuda(), prototypes.cuda(), precision="bfloat16")
    assert ids_cuda.device.type == "cuda" and sq_dist.device.type == "cuda"
    assert float((ids_cuda.cpu() == ids_cpu).float().mean()) > 0.999
    result = kmeans(points.cuda(), 64, generator=torch.Generator(device="cuda").manual_seed(0), max_iterations=5)
    assert result.prototypes.device.type == "cuda"
    for before, after in zip(result.distortion, result.distortion[1:], strict=False):
        assert after <= before * (1 + 1e-6)


def test_quantizers_and_q_learning_on_cuda():
    data = torch.randn(1000, 6, generator=torch.Generator().manual_seed(1)).cuda()
    quantizer, _ = Quantizer.fit(data, 32, generator=torch.Generator(device="cuda").manual_seed(0), max_iterations=3)
    assert torch.equal(quantizer.encode(data).cpu(), quantizer.to("cpu").encode(data.cpu()))
    union = UnionQuantizer().unite(0, torch.arange(6, device="cuda"), quantizer)
    ids = union.encode(data, torch.zeros(1000, dtype=torch.int64, device="cuda"))
    assert ids.device.type == "cuda"
    q_values = zeros_q_values(2, 2, 32, device="cuda")
    generator = torch.Generator(device="cuda").manual_seed(0)
    rows = ids[:100]
    actions = epsilon_greedy(q_values, rows, 0.2, generator)
    td = td_update(
        q_values,
        rows,
        actions,
        torch.ones(100, device="cuda"),
        ids[100:200],
        torch.zeros(100, dtype=torch.bool, device="cuda"),
        torch.ones(100, dtype=torch.bool, device="cuda"),
        alpha=0.5,
        gamma=0.9,
    )
    assert td.device.type == "cuda" and float(q_values.sum()) > 0


def test_sequential_collision_rule_on_cuda_equals_the_cpu_on_a_hand_built_scene():
    """A queue at the door and two agents heading for one spot: the bounded, sync-free rounds of the GPU path give
    the CPU's (convergence-tested) outcome."""
    from pedrl.sim.actions import velocities_from
    from pedrl.sim.motion import move_agents_sequential

    env = paper_room(width=8.0, length=10.0, door_width=1.5).room(num_replicas=1, num_agents=4)
    positions = torch.tensor([[[4.0, 9.0], [4.0, 8.1], [3.0, 5.0], [5.0, 5.0]]])
    speeds = torch.tensor([[1.0, 2.5, 2.0, 2.0]])
    headings = torch.tensor([[1.5708, 1.5708, 0.0, 3.1416]])  # up, up, towards each other
    kwargs = dict(active=torch.ones(1, 4, dtype=torch.bool))
    velocities = velocities_from(speeds=speeds, headings=headings)
    priority = torch.tensor([[0.3, 0.1, 0.2, 0.4]])
    cpu = move_agents_sequential(
        positions=positions, velocities=velocities, motion=env.motion_constants, priority=priority, **kwargs
    )
    cuda_env = paper_room(width=8.0, length=10.0, door_width=1.5).room(num_replicas=1, num_agents=4, device="cuda")
    cuda = move_agents_sequential(
        positions=positions.cuda(),
        velocities=velocities.cuda(),
        motion=cuda_env.motion_constants,
        priority=priority.cuda(),
        sync_free=True,
        **{**kwargs, "active": kwargs["active"].cuda()},
    )
    assert bool(cpu.blocked.any()) and bool(cpu.reached.any())  # the scene exercises both
    for field in ("blocked", "crashed_wall", "crashed_agent", "reached"):
        assert torch.equal(getattr(cuda, field).cpu(), getattr(cpu, field)), field
    torch.testing.assert_close(cuda.positions.cpu(), cpu.positions, rtol=0, atol=1e-5)


def test_a_training_trial_runs_on_cuda_and_learns_like_the_cpu():

    from pedrl.algos import VQQL, RunSpec

    rates = {}
    for device in ("cpu", "cuda"):
        run = RunSpec(
            env=paper_room(width=8.0, length=10.0, door_width=1.5).room,
            vq={"num_prototypes": 32, "max_iterations": 3},
            processes=4,
            device=device,
            progress=False,
            tensorboard=False,
        )
        trainer = VQQL(run, num_agents=4, trials=1, gather_trials=1)
        env = trainer.env_for(4)
        env.reset(seed=0)
        phase = trainer.phases()[0]
        states, num_sensed = trainer.gather(phase, env, None)[:2]
        quantizer, _ = trainer.fit_quantizer(phase, states, num_sensed, None)
        q_values = torch.zeros((4, 4, quantizer.num_prototypes, env.num_actions), device=device)
        successes = [
            float(trainer.run_trial(env, quantizer, q_values, epsilon=0.2, learn=True).success_rate.mean())
            for _ in range(40)
        ]
        rates[device] = sum(successes[-20:]) / 20
    assert abs(rates["cuda"] - rates["cpu"]) < 0.25  # within the noise of 20 trials of 16 agents
