"""The fused trial (`pedrl.trial.fused`) against the torch reference, within the tolerances the docs state:

- features: distances, speeds and relative speeds within 1e-5 relative (1e-5 absolute below 1), angles within 1e-5
  rad (modulo 2 pi), the numbers of sensed neighbours equal;
- one decision from the same state, actions and order of action: positions within 1e-4 m, speeds within 1e-4 m/s,
  rewards within 1e-3, and the contact, exit and goal flags equal for at least 99 % of the agents (a move that
  grazes a body or a wall within float32 rounding can go either way);
- encoding: the prepared features within the feature tolerance, the state ids equal for at least 99 % of the states
  (near-ties of two prototypes can go either way);
- a seed gives the same trial, bit for bit, at 1 and 2 threads.

The learning curves of the two paths agree within the seed spread: the slow test at the end.
"""

import math

import numpy as np
import pytest
import torch
from omegaconf import open_dict

from pedrl._numba import numba_available
from pedrl.algos.registry import env_factory
from pedrl.io import read_csv
from pedrl.rl.policy import TabularPolicy
from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.actions import GOAL_SPEED_RATIOS, GOAL_TURN_RATIOS
from pedrl.sim.motion import Simultaneous, Yield
from pedrl.sim.motion.common import neighbour_search
from pedrl.sim.sensing import observe
from pedrl.train import train as train_run
from pedrl.trial import fused
from pedrl.trial.crowd import run_crowd
from pedrl.trial.loop import Learner
from pedrl.trial.rollout import gather
from pedrl.vq.encoder import EncoderSettings, StateEncoder
from pedrl.vq.factored import FactoredQuantizer, factor_specs
from pedrl.vq.quantizer import ProcessQuantizers, Quantizer, UnionQuantizer
from tests.conftest import compose_config

pytestmark = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")

SCENES = [("paper_room", 20, "stop"), ("paper_room", 20, "yield"), ("bottleneck", 30, "headway"),
          ("corner", 7, "slide"), ("corridor", 30, "yield"), ("four_exits", 40, "stop")]  # fmt: skip
ANGLE_COLUMNS = [1] + [5 + 3 * i for i in range(7)] + [25, 27]


GOAL_FRAME = {"action_frame": "goal", "speed_ratios": GOAL_SPEED_RATIOS, "turn_ratios": GOAL_TURN_RATIOS}
"""The ``goal`` action frame, for the decision's tests (its actions aim at the door or the waypoint)."""


def scene(name: str, agents: int, contact: str, seed: int, replicas: int = 4, frame: str = "heading") -> RoomEnv:
    """A room of the scenario after a reset and 3 random decisions, with random speeds and headings."""
    settings = {"_target_": "pedrl.sim.RoomEnv", "motion": {"name": contact}} | (GOAL_FRAME if frame == "goal" else {})
    env = env_factory(settings, {"name": name})(num_replicas=replicas, num_agents=agents)
    env.reset(seed=seed)
    generator = torch.Generator().manual_seed(seed)
    for _ in range(3):
        env.step(torch.randint(81, (replicas, agents), generator=generator))
    env.speeds = torch.rand(env.speeds.shape, generator=generator) * env.params.max_speed
    env.headings = (torch.rand(env.headings.shape, generator=generator) * 2 - 1) * math.pi
    env.velocities = torch.stack((env.speeds * env.headings.cos(), env.speeds * env.headings.sin()), -1)
    return env


def fused_features(env: RoomEnv, present: torch.Tensor, velocity: np.ndarray | None = None):
    """The kernel's features and numbers sensed (and, into ``velocity`` where given, the neighbours' velocities)."""
    from pedrl.sim.sensing_kernel import NO_VELOCITY, sense_room

    rooms, agents = env.num_replicas, env.num_agents
    features = np.zeros((rooms, agents, env.num_features), np.float32)
    num_sensed = np.zeros((rooms, agents), np.int64)
    size = max(agents, env.geometry.num_walls)
    state, search, params = env.state.arrays(), neighbour_search(), env.params
    for r in range(rooms):
        sense_room(r, state, present.numpy(), env.geometry.kernel_walls(), params.num_neighbours, params.num_walls,
                   search, features, num_sensed, np.empty((2, size), np.float32), np.empty((2, size), np.int64),
                   NO_VELOCITY if velocity is None else velocity)  # fmt: skip
    return features, num_sensed


def assert_features_close(actual: torch.Tensor, expected: torch.Tensor) -> None:
    """Distances and speeds within 1e-5 relative (absolute below 1), angles within 1e-5 rad modulo 2 pi."""
    difference = (actual - expected).abs()
    angles = torch.zeros(actual.shape[-1], dtype=torch.bool)
    angles[[c for c in ANGLE_COLUMNS if c < actual.shape[-1]]] = True
    difference[..., angles] = torch.minimum(difference[..., angles], 2 * math.pi - difference[..., angles])
    bound = torch.where(angles, torch.full_like(expected, 1e-5), 1e-5 * expected.abs().clamp_min(1.0))
    worst = (difference - bound).max()
    assert worst <= 0, f"a feature differs by {float(difference.max())} (over its bound by {float(worst)})"


@pytest.mark.parametrize(("name", "agents", "contact"), SCENES)
@pytest.mark.parametrize("seed", [0, 1])
def test_features_match_the_torch_sensing(name, agents, contact, seed):
    env = scene(name, agents, contact, seed)
    present = env.active & (torch.rand(env.active.shape, generator=torch.Generator().manual_seed(seed)) < 0.8)
    expected = observe(
        positions=env.positions, velocities=env.velocities, headings=env.headings, speeds=env.speeds,
        observers=present, sensed=present, geometry=env.geometry, goals=env.targets(),
        num_neighbours=env.params.num_neighbours, num_walls=env.params.num_walls,
    )  # fmt: skip
    velocity = np.full((*env.active.shape, env.params.num_neighbours, 2), np.float32(7.0))  # every entry is written
    features, num_sensed = fused_features(env, present, velocity)
    assert int(present.sum()) > agents  # a real scene
    assert torch.equal(torch.from_numpy(num_sensed), expected.num_sensed)
    assert_features_close(torch.from_numpy(features), expected.features)
    torch.testing.assert_close(torch.from_numpy(velocity), expected.neighbour_velocity, rtol=0, atol=1e-5)


def test_the_feature_check_fails_on_a_wrong_feature():
    """Control: a distance off by 1e-3 relative, or an angle off by 1e-4 rad, fails the tolerance."""
    expected = torch.tensor([[1.0, 0.5, 20.0]])
    for column, error in ((2, 0.02), (1, 1e-4)):
        actual = expected.clone()
        actual[0, column] += error
        with pytest.raises(AssertionError):
            assert_features_close(actual, expected)
    assert_features_close(expected + torch.tensor([[0.0, 2 * math.pi, 0.0]]), expected)  # an angle modulo 2 pi


def fused_step(env: RoomEnv, actions: torch.Tensor, draws: torch.Tensor) -> tuple[tuple, tuple]:
    """One decision of every room by ``act_room`` from ``env``'s state: the state and the events after it."""
    from pedrl.sim.step_kernel import NO_COMMANDS, Events, Work, act_room, act_scratch

    rooms, agents = env.num_replicas, env.num_agents
    state = env.state.clone().arrays()
    work = Work.allocate(rooms, agents, env.num_substeps)
    work.draws[:] = draws.numpy()
    events = Events.allocate(rooms, agents)
    scratch, inputs = act_scratch(agents), fused.room_inputs(env)
    for r in range(rooms):
        act_room(r, state, actions.numpy(), NO_COMMANDS, inputs.room, inputs.walls, inputs.exits, inputs.routes,
                 work, events, scratch)  # fmt: skip
    return state, events


@pytest.mark.parametrize(
    ("name", "agents", "contact", "frame"),
    [(*s, "heading") for s in SCENES] + [("paper_room", 20, "yield", "goal"), ("corner", 7, "headway", "goal")],
)
def test_a_decision_matches_the_room_step(name, agents, contact, frame):
    """From 8 random states, the same actions and the same order of action (torch's draws of the step), in both
    action frames (the goal frame's round the corner's waypoint too)."""
    mismatched, total = 0, 0
    for seed in range(8):
        env = scene(name, agents, contact, seed, frame=frame)
        actions = torch.randint(81, env.active.shape, generator=torch.Generator().manual_seed(seed))
        draws = torch.rand(env.active.shape, generator=torch.Generator().set_state(env.generator.get_state()))
        state, events = fused_step(env, actions, draws)
        acting = env.active.clone()
        _, reward, terminated, truncated, info = env.step(actions)
        flags = (info["crashed_wall"], info["crashed_agent"], terminated, info["reached"])
        agree = acting.clone()
        for flag, mine in zip(flags, (events[3], events[4], events[1], events[2]), strict=True):
            agree &= flag == torch.from_numpy(mine)
        mismatched += int((acting & ~agree).sum())
        total += int(acting.sum())
        close = agree.unsqueeze(-1)
        assert torch.allclose(torch.from_numpy(state[0]) * close, env.positions * close, atol=1e-4, rtol=0)
        assert torch.allclose(torch.from_numpy(state[3]) * agree, env.speeds * agree, atol=1e-4, rtol=0)
        assert torch.allclose(torch.from_numpy(events[0]) * agree, reward * agree, atol=1e-3, rtol=0)
        assert torch.equal(torch.from_numpy(state[4]), env.active)
        assert torch.equal(torch.from_numpy(state[8]), env.stage)
        assert torch.allclose(torch.from_numpy(state[6]), env.targets(), atol=1e-5, rtol=0)
    assert mismatched <= 0.01 * total, f"{mismatched} of {total} agents' flags differ"
    assert total > 100


def policies(env: RoomEnv, processes: int) -> dict[str, TabularPolicy]:
    """A policy of each quantizer kind over ``env``'s observations (random void fillings, log distances): one shared,
    one per process, IN-VQQL's union and a factored one."""
    settings = EncoderSettings.for_room(env, void_features="random", distance_transform="log")
    generator = torch.Generator().manual_seed(0)
    env.reset(seed=0)
    states = gather(env, StateEncoder(settings), None, trials=1, epsilon=1.0, processes=processes, generator=generator)
    shared, _ = Quantizer.fit(states.states, 300, generator=generator, max_iterations=10)
    parts = [Quantizer.fit(states.states, 300, generator=generator, max_iterations=5)[0] for _ in range(processes)]
    union = UnionQuantizer()
    for sensed in (0, 3, 7):
        index = torch.cat((torch.arange(3 + 3 * sensed), torch.arange(24, 28)))
        union = union.unite(sensed, index, Quantizer.fit(states.states[:, index], 40 + sensed, generator=generator,
                                                        max_iterations=5)[0])  # fmt: skip
    neighbour = {"num_prototypes": 40, "weights": {"distance": 2}}
    specs = factor_specs({"own": {"num_prototypes": 60}, "neighbour": neighbour, "wall": {"num_prototypes": 16}})
    factored, _ = FactoredQuantizer.fit(states.states, states.num_sensed, specs, num_neighbours=7, num_walls=2,
                                        max_states=20_000, generator=generator, max_iterations=5)  # fmt: skip
    kinds = {"shared": shared, "per_process": ProcessQuantizers(parts), "union": union, "factored": factored}
    return {
        kind: TabularPolicy(StateEncoder(settings, q), torch.randn(processes, 1, q.num_prototypes, 81))
        for kind, q in kinds.items()
    }


@pytest.mark.parametrize("kind", ["shared", "per_process", "union"])
def test_encoding_matches_the_encoder(kind):
    from pedrl.vq.encode_kernel import encode_agent, pack_encoder

    policy = policies(scene("paper_room", 20, "yield", 0), 4)[kind]
    env = scene("paper_room", 20, "yield", 0)
    present = env.active
    assert int(present.sum()) > 40
    features, num_sensed = fused_features(env, present)
    void = torch.rand(env.num_replicas * env.num_agents, 3 * 7 + 1, generator=torch.Generator().manual_seed(1))
    encoder = policy.encoder
    encoder._void_uniform = void
    info = {"num_sensed": torch.from_numpy(num_sensed), "decision": 1}
    expected = policy.rows(torch.from_numpy(features), info, torch.Generator()).view(env.num_replicas, -1)
    base = policy.layout.of(env.num_replicas, env.num_agents, env.device)[1].view(env.num_replicas, -1)
    packed = pack_encoder(encoder, policy.num_processes)
    void_settings = encoder.settings.kernel()
    assert void_settings.random_void and void_settings.log_distances and void_settings.num_neighbours == 7
    buffers = (np.empty(28, np.float32), np.empty(28, np.float32), np.empty(128, np.int64), np.empty(16, np.float32))
    ids = torch.zeros_like(expected)
    for r in range(env.num_replicas):
        for i in range(env.num_agents):
            if present[r, i]:
                fills = void.view(env.num_replicas, -1, 22).numpy()
                found = encode_agent(r, i, r, features, num_sensed, fills, void_settings, packed.arrays, packed.tree,
                                     *buffers)  # fmt: skip
                ids[r, i] = base[r, i] + found
    same = (ids == expected)[present]
    assert same.float().mean() >= 0.99, f"{int((~same).sum())} of {same.numel()} ids differ"


def train(
    fused_trial: bool, seed: int, trials: int, threads: int = 1, rooms_per_process: int = 1
) -> tuple[list[float], torch.Tensor]:
    """Success rates of ``trials`` learning trials in 8 small rooms (``rooms_per_process`` E of them learning into
    each process's tables), and the tables after them."""
    env = paper_room(width=12, length=12, door_width=3).room(num_replicas=8, num_agents=10, motion=Yield())
    shared = policies(env, 8 // rooms_per_process)["shared"]
    policy = TabularPolicy(shared.encoder, shared.q_values.zero_(), rooms_per_process=rooms_per_process)
    generator = torch.Generator().manual_seed(seed)
    env.reset(seed=seed)
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        learner = Learner(policy, epsilon=0.2, generator=generator, learn=True, alpha=0.3, gamma=0.9)
        rates = [float(run_crowd(env, learner, fused=fused_trial).stats.success_rate.mean()) for _ in range(trials)]
    finally:
        torch.set_num_threads(previous)
    return rates, policy.q_values


@pytest.mark.parametrize("rooms_per_process", [1, 2])
def test_a_seed_gives_the_same_trial_at_any_thread_count(rooms_per_process):
    one, tables_one = train(True, 3, 4, threads=1, rooms_per_process=rooms_per_process)
    two, tables_two = train(True, 3, 4, threads=2, rooms_per_process=rooms_per_process)
    assert one == two and torch.equal(tables_one, tables_two)
    other, _ = train(True, 4, 4, threads=2, rooms_per_process=rooms_per_process)
    assert other != one  # control: another seed, another run


def test_the_td_update_averages_entries_as_the_torch_reference():
    """Two rooms of one process, agents hitting the same (row, action): the one TD kernel (``td_batch``, which the
    fused trial runs over a process's rooms) gives td_update_torch's errors and tables to the bit (duplicates
    averaged, left agents not bootstrapping, inactive ones skipped), and its sum and count of updates."""
    from pedrl.rl.kernels import td_batch, td_scratch
    from pedrl.rl.qlearning import td_update_torch

    generator = torch.Generator().manual_seed(0)
    table = torch.randn(6, 81, generator=generator)
    rows = torch.tensor([1, 1, 2, 3, 1, 4, 2, 5])
    actions = torch.tensor([7, 7, 0, 80, 7, 3, 0, 1])
    reward = torch.randn(8, generator=generator)
    next_rows = torch.tensor([0, 5, 4, 3, 2, 2, 1, 0])
    left = torch.tensor([False, True, False, False, False, False, True, False])
    acting = torch.tensor([True, True, True, False, True, True, True, True])
    expected_table = table.clone()
    expected = td_update_torch(expected_table.view(1, 1, 6, 81), rows, actions, reward, next_rows, left, acting,
                               alpha=0.3, gamma=0.9)  # fmt: skip
    errors = np.zeros(8, np.float32)
    arrays = (table, rows, actions, reward, next_rows, left, acting)
    total, count = td_batch(*(a.numpy() for a in arrays), np.float32(0.3), np.float32(0.9), errors, *td_scratch(8))
    assert count == 7 and total == pytest.approx(float(expected.abs().sum()), rel=1e-6)
    assert torch.equal(torch.from_numpy(errors), expected)
    assert torch.equal(table, expected_table)


def test_fused_must_be_a_boolean_or_null(compose, tmp_path):
    from pedrl.algos.registry import build_trainer

    with pytest.raises(ValueError, match=r"^fused='yes' is invalid: must be true, false or null$"):
        build_trainer(compose("train", ["debug=default", "fused=yes"]), tmp_path)
    with pytest.raises(
        ValueError, match=r"^fused=true is invalid: the fused trial cannot run with motion=simultaneous"
    ):
        build_trainer(compose("train", ["debug=default", "fused=true", "motion=simultaneous"]), tmp_path)


def test_kernel_threads_follow_torch_s_and_sleep_when_idle():
    """The fused trial runs on torch's thread count (``threads``, or a parallel sweep's share of the cores), in
    numba's workqueue layer, whose idle threads sleep instead of spinning against torch's or another job's."""
    import numba

    train(True, 0, 1, threads=1)
    assert numba.get_num_threads() == 1 and numba.threading_layer() == "workqueue"
    train(True, 0, 1, threads=2)
    assert numba.get_num_threads() == min(2, numba.config.NUMBA_NUM_THREADS)


def test_fused_true_is_refused_in_one_line_where_it_cannot_run():
    env = paper_room(width=10, length=10).room(num_replicas=2, num_agents=4, motion=Simultaneous())
    policy = policies(paper_room(width=10, length=10).room(num_replicas=2, num_agents=4), 2)["shared"]
    with pytest.raises(ValueError, match=r"^fused=true is invalid: .*motion=simultaneous"):
        run_crowd(env, Learner(policy, epsilon=0.1, generator=torch.Generator(), learn=False), fused=True)
    learner = Learner(policy, epsilon=0.1, generator=torch.Generator(), learn=False)
    stats = run_crowd(env, learner, fused=None).stats  # null: the torch loop
    assert stats.agent_decisions > 0


@pytest.mark.slow
def test_learning_curves_of_the_two_paths_agree_within_the_seed_spread(tmp_path):
    """experiment=quick_vqql (one iteration of 150 trials), seeds 0, 1, 2 on each path: both learn (the success of
    the last 20 trials beats the first 5 by 0.1), and their final successes differ by less than twice the larger
    seed spread (at least 0.03)."""
    finals = {}
    for path in ("true", "false"):
        runs = []
        for seed in range(3):
            cfg = compose_config("train", ["experiment=quick_vqql", "algo.iterations=1", f"fused={path}",
                                           f"seed={seed}", "logger=none", "threads=1"])  # fmt: skip
            with open_dict(cfg):
                cfg.progress = False
            train_run(cfg, run_dir=tmp_path / f"{path}{seed}")
            rates = [float(row["success_rate_mean"]) for row in read_csv(tmp_path / f"{path}{seed}/learning_curve.csv")]
            assert np.mean(rates[-20:]) > np.mean(rates[:5]) + 0.1, (path, seed)
            runs.append(float(np.mean(rates[-20:])))
        finals[path] = runs
    spread = max(np.std(finals["true"]), np.std(finals["false"]), 0.03)
    assert abs(np.mean(finals["true"]) - np.mean(finals["false"])) < 2 * spread, finals


@pytest.mark.parametrize("algo", ["it_vqql", "in_vqql"])
def test_a_walker_that_senses_no_neighbour_learns_on_both_paths(algo, tmp_path):
    """``env.num_neighbours=0`` (an ablation: the door and the walls only) trains on the fused and the torch path, as
    it did before the encoder refused it; -1 is refused by the room and the encoder alike, in one line."""
    import functools

    from pedrl.algos import INVQQL, ITVQQL, RunSpec

    paper = paper_room(width=12.0, length=12.0, door_width=3.0)
    room = functools.partial(paper.room, max_decisions=30, num_neighbours=0)
    for fused_path in (True, False):
        run = RunSpec(env=room, vq={"num_prototypes": 32, "max_iterations": 2}, processes=2, progress=False,
                      tensorboard=False, seed=1, run_dir=tmp_path, fused=fused_path)  # fmt: skip
        if algo == "it_vqql":
            trainer = ITVQQL(run, trials=2, gather_trials=2, iterations=2, num_agents=4)
        else:
            trainer = INVQQL(run, trials=2, gather_trials=2, stages=[1, 2])
        assert trainer.encoder_settings.num_features == 3 + 2 * 2
        result = trainer.fit()
        assert 0.0 <= result.final["success_rate_mean"] <= 1.0
    encoder = functools.partial(EncoderSettings, num_walls=2, max_distance=10.0, max_speed=2.0)
    for build in (lambda: paper_room().room(num_neighbours=-1), lambda: encoder(num_neighbours=-1)):
        with pytest.raises(ValueError, match=r"^num_neighbours=-1 is invalid: must be an integer >= 0$"):
            build()
