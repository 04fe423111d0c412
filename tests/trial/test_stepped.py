"""CompiledRoom: the compiled kernels step a room decision by decision with the torch step's contract."""

import pytest
import torch

from pedrl.scenarios import paper_room
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.motion import Continuous, Simultaneous, Yield
from pedrl.sim.params import RoomParams
from pedrl.trial.loop import crowd_loop
from pedrl.trial.stepped import CompiledRoom

pytestmark = pytest.mark.skipif(not __import__("pedrl._numba", fromlist=["x"]).numba_available(), reason="numba")


def _room(motion=None, replicas=6, agents=40):
    params = RoomParams(motion=motion if motion is not None else Yield(order="door_first"))
    return paper_room(width=12.0, length=14.0).room(params, num_replicas=replicas, num_agents=agents)


def _greedy(seed=0):
    return GreedyDoorController(epsilon=0.1, generator=torch.Generator().manual_seed(seed))


def test_compiled_step_keeps_the_torch_steps_contract():
    room = CompiledRoom(_room())
    obs, info = room.reset(seed=3)
    assert obs.shape == (6, 40, room.num_features) and info["decision"] == 0
    held = room.active  # a caller's tensor of the decision before: the kernels must not change it
    before = held.clone()
    obs, reward, terminated, truncated, info = room.step(_greedy().act(room, obs, info))
    assert torch.equal(held, before)
    assert reward.shape == terminated.shape == truncated.shape == (6, 40) and info["decision"] == 1
    torch_room = _room()
    torch_obs, torch_info = torch_room.reset(seed=3)
    assert set(info) == set(torch_room.step(_greedy().act(torch_room, torch_obs, torch_info))[4])  # the same keys
    assert torch.equal(info["neighbour_mask"].sum(-1), info["num_sensed"])
    assert bool((obs[~room.active] == 0).all())  # who left gets 0, as from the torch step
    assert float(info["speed"].max()) <= room.params.max_speed + 1e-6


@pytest.mark.parametrize("motion", [Yield(order="door_first"), Continuous(contact="yield", time_gap=0.4)])
def test_compiled_trial_matches_the_torch_trial(motion):
    """The greedy walker's trial through the kernels and through the torch step: the same crowd within the twins'
    tolerances (the order of the movers is drawn from other streams)."""
    figures = {}
    for name in ("torch", "compiled"):
        env = _room(motion)
        env.reset(seed=5)
        stats = crowd_loop(CompiledRoom(env) if name == "compiled" else env, _greedy()).stats
        figures[name] = (float(stats.success_rate.mean()), float(stats.evacuation_time.mean()),
                         float(stats.crashes_agent.mean()))  # fmt: skip
    (ok_t, time_t, crash_t), (ok_c, time_c, crash_c) = figures["torch"], figures["compiled"]
    assert ok_t == ok_c == 1.0
    assert abs(time_t - time_c) <= 0.15 * time_t, figures
    assert abs(crash_t - crash_c) <= 0.5 + 0.5 * crash_t, figures


def test_compiled_trial_same_seed_same_numbers_and_no_overlap():
    runs = []
    for _ in range(2):
        env = _room()
        env.reset(seed=9)
        run = crowd_loop(CompiledRoom(env), _greedy(), record=True)
        runs.append(run)
    assert (runs[0].record.positions == runs[1].record.positions).all()
    positions, inside = torch.from_numpy(runs[0].record.positions), torch.from_numpy(runs[0].record.in_room)
    gaps = torch.cdist(positions, positions)  # (R, T, N, N)
    both = inside.unsqueeze(-1) & inside.unsqueeze(-2) & ~torch.eye(40, dtype=torch.bool)
    assert float(gaps[both].min()) >= 2 * 0.4 - 1e-3  # bodies of 0.4 m never overlap


def test_a_network_runs_on_the_kernels_only_where_the_chooser_allows_them():
    from pedrl.trial.crowd import choose_path

    class Network:  # a controller that acts in torch between compiled decisions
        stepped = True

    assert choose_path([_room()], Network(), None).name == "fused"
    assert choose_path([_room()], Network(), None, placed=True).name == "torch"
    assert choose_path([_room(Simultaneous())], Network(), None).name == "torch"
    with pytest.raises(ValueError, match="^fused=true is invalid: the fused trial cannot run with motion=simul"):
        choose_path([_room(Simultaneous())], Network(), True)


def test_each_trial_walks_the_routes_drawn_at_its_own_placement():
    """In a room whose exit is out of sight (the partition room) each walker's route is drawn when it is placed: the
    kernels' room aims every walker at the same waypoint as the torch room, at every decision of several trials.
    (Before, the routes were read once, before the first placement: every walker aimed at the exit through the
    partition.)"""
    from pedrl.configs import env_factory

    scenario = {"name": "custom", "geometry": "POLYGON ((0 0, 9.9 0, 9.9 9, 10.1 9, 10.1 0, 20 0, 20 12, 0 12, 0 0))",
                "exits": [[20.0, 1.0, 20.0, 2.6]], "spawn": [[0.5, 0.5, 9.4, 8.0]]}  # fmt: skip
    factory = env_factory({"_target_": "pedrl.sim.RoomEnv", "motion": {"name": "continuous", "contact": "yield",
                           "time_gap": 0.4},
                           "action_frame": "goal", "agent_radius": 0.2, "max_speed": 1.34, "max_decisions": 40,
                           "speed_ratios": [0.0, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98, 1.0]}, scenario)  # fmt: skip
    # one walker a room: no order of movers to differ between the two (they draw it from other streams)
    reference, kernels = factory(num_replicas=4, num_agents=1), CompiledRoom(factory(num_replicas=4, num_agents=1))
    walker = GreedyDoorController()
    for seed in (4, 5):
        obs, info = reference.reset(seed=seed)
        compiled, _ = kernels.reset(seed=seed)
        assert bool((reference.spawns.route_length > 0).all())  # every start is out of sight of the exit
        for _ in range(12):
            torch.testing.assert_close(kernels.targets(), reference.targets())
            torch.testing.assert_close(compiled, obs, atol=1e-4, rtol=1e-4)
            actions = walker.act(reference, obs, info)
            obs, _, _, _, info = reference.step(actions)
            compiled, *_ = kernels.step(actions)
    assert bool((reference.stage > 0).any())  # the walk went past a waypoint
