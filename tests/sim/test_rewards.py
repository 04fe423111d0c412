"""Rewards per decision (paper Table 2)."""

import dataclasses
import inspect
import itertools
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from pedrl._numba import numba_available
from pedrl.cli import CONFIG_DIR
from pedrl.scenarios import paper_room
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.params import RoomParams
from pedrl.sim.rewards import (
    PASSING_SIDES,
    REWARD_DEFAULTS,
    RewardTable,
    commanded_deviation,
    compute_rewards,
    crowded_kernel,
    deviation_kernel,
    in_company,
    passing_kernel,
    reward_kernel,
    unpriced_in_company,
    wrong_side_passing,
)
from pedrl.trial.stepped import CompiledRoom


def test_reward_priority_goal_then_wall_then_agent_then_default():
    # columns: nothing, agent crash, wall crash, wall and agent crash, reached, reached after a crash, inactive
    reached = torch.tensor([[False, False, False, False, True, True, True]])
    crashed_wall = torch.tensor([[False, False, True, True, False, True, True]])
    crashed_agent = torch.tensor([[False, True, False, True, False, True, False]])
    acting = torch.tensor([[True, True, True, True, True, True, False]])
    reward = compute_rewards(
        table=RewardTable(), reached=reached, crashed_wall=crashed_wall, crashed_agent=crashed_agent, acting=acting
    )
    assert reward.dtype == torch.float32
    assert reward.tolist() == [[-1.0, -4.0, -15.0, -15.0, 100.0, 100.0, 0.0]]


def test_reward_values_come_from_the_table():
    table = RewardTable(goal=1.0, crash_wall=-2.0, crash_agent=-3.0, default=-0.5)
    flags = torch.tensor([[True, False, False, False]])
    reward = compute_rewards(
        table=table,
        reached=flags,
        crashed_wall=flags.roll(1, -1),
        crashed_agent=flags.roll(2, -1),
        acting=torch.ones(1, 4, dtype=torch.bool),
    )
    assert reward.tolist() == [[1.0, -2.0, -3.0, -0.5]]


def test_the_rewards_have_one_default_set():
    """The table, the room's settings and conf/env/room.yaml hold the same defaults: a second set anywhere fails."""
    assert RewardTable().settings() == REWARD_DEFAULTS == RoomParams().rewards.settings()
    assert REWARD_DEFAULTS == {"reward_goal": 100.0, "reward_crash_wall": -15.0, "reward_crash_agent": -4.0,
                               "reward_default": -1.0, "reward_progress": 1.0, "reward_deviation": 0.0,
                               "reward_passing": 0.0}  # fmt: skip
    room = OmegaConf.load(Path(CONFIG_DIR) / "env" / "room.yaml")
    assert {name: float(room[name]) for name in REWARD_DEFAULTS} == REWARD_DEFAULTS
    defaults = {name: RoomParams.__dataclass_fields__[name].default for name in REWARD_DEFAULTS}
    assert defaults == REWARD_DEFAULTS


def test_the_table_checks_each_reward_and_names_its_setting():
    assert RewardTable(goal=3).goal == 3.0 and isinstance(RewardTable(goal=3).goal, float)
    with pytest.raises(ValueError, match=r"^reward_crash_wall=-1e\+38 is invalid: must be a number in \[-1e\+06"):
        RewardTable(crash_wall=-1e38)
    with pytest.raises(ValueError, match=r"^reward_progress=-1 is invalid: must be a number in \[0, 1e\+06\]"):
        RewardTable(progress=-1)
    with pytest.raises(ValueError, match="reward_goal=True"):
        RewardTable(goal=True)
    params = RoomParams(reward_goal=7.0, reward_progress=2.0)
    assert params.rewards == RewardTable(goal=7.0, progress=2.0)
    assert RewardTable.of(params).settings() == {name: getattr(params, name) for name in params.rewards.settings()}


def test_the_progress_term_is_paid_per_metre_to_acting_agents_only():
    acting = torch.tensor([[True, True, False]])
    none = torch.zeros(1, 3, dtype=torch.bool)
    progress = torch.tensor([[2.0, -0.5, 3.0]])
    table = RewardTable(default=-1.0, progress=3.0)
    reward = compute_rewards(
        table=table, reached=none, crashed_wall=none, crashed_agent=none, acting=acting, progress=progress
    )
    assert reward.dtype == torch.float32 and reward.tolist() == [[5.0, -2.5, 0.0]]


def test_the_deviation_prices_a_command_off_top_speed_straight_at_the_goal():
    """Analytic cases: straight at top speed 0, half speed 0.5, 45 degrees off 0.25, turned round at rest 2; the
    greedy walker's command costs nothing in a room, a walker that turns 45 degrees pays a quarter of the price."""
    positions = torch.zeros(1, 4, 2)
    targets = torch.tensor([[[10.0, 0.0], [0.0, 10.0], [-3.0, -3.0], [-5.0, 0.0]]])
    speeds = torch.tensor([[2.0, 1.0, 2.0, 0.0]])
    headings = torch.tensor([[0.0, torch.pi / 2, -torch.pi / 2, 0.0]])
    deviation = commanded_deviation(speeds, headings, positions, targets, max_speed=2.0)
    torch.testing.assert_close(deviation, torch.tensor([[0.0, 0.5, 0.25, 2.0]]))
    speed_only = commanded_deviation(speeds, headings, positions, targets, max_speed=2.0, turn=0.0)
    torch.testing.assert_close(speed_only, torch.tensor([[0.0, 0.5, 0.0, 1.0]]))  # deviation_turn=0: speed alone
    with pytest.raises(ValueError, match=r"^deviation_turn=-1 is invalid: must be a number in \[0, 10\]"):
        paper_room().room(num_agents=2, deviation_turn=-1)
    with pytest.raises(ValueError, match=r"^reward_deviation=1 is invalid: must be a number in \[-1e\+06, 0\]"):
        RewardTable(deviation=1)
    env = paper_room(width=10.0, length=12.0).room(
        num_agents=4, action_frame="goal", reward_deviation=-8.0, reward_progress=0.0, reward_default=-1.0,
        speed_ratios=[0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1],
        turn_ratios=[-0.5, -0.25, -0.1, -0.05, 0, 0.05, 0.1, 0.25, 0.5],
    )  # fmt: skip
    obs, info = env.reset(seed=0)
    greedy = GreedyDoorController().act(env, obs, info)
    _, reward, _, _, info = env.step(greedy)
    plain = info["crashed_agent"] | info["crashed_wall"] | info["reached"]
    assert (~plain).sum() >= 2 and torch.equal(reward[~plain], torch.full_like(reward[~plain], -1.0))
    env.reset(seed=0)
    _, turned, _, _, info = env.step(torch.full_like(greedy, 8 * 9 + 7))  # top speed, 0.25 pi off the bearing
    plain = info["crashed_agent"] | info["crashed_wall"] | info["reached"]
    assert (~plain).sum() >= 2
    torch.testing.assert_close(turned[~plain], torch.full_like(turned[~plain], -1.0 - 8.0 * 0.25))
    half = paper_room(width=10.0, length=12.0).room(
        num_agents=4, action_frame="goal", reward_deviation=-8.0, reward_progress=0.0, reward_default=-1.0,
        speed_ratios=env.params.speed_ratios, turn_ratios=env.params.turn_ratios, deviation_turn=0.5,
    )  # fmt: skip
    half.reset(seed=0)
    _, turned, _, _, info = half.step(torch.full_like(greedy, 8 * 9 + 7))  # the turn priced at half
    plain = info["crashed_agent"] | info["crashed_wall"] | info["reached"]
    torch.testing.assert_close(turned[~plain], torch.full_like(turned[~plain], -1.0 - 8.0 * 0.125))


def test_the_deviation_radius_prices_a_free_walker_alone():
    """Analytic: with deviation_radius 2, the pair 1.5 m apart deviates for free, the walker 5 m from both pays, an
    absent agent neither counts as company nor is priced beyond what it is given; radius 0 leaves the price as it is;
    a bad radius gets one line."""
    positions = torch.tensor([[[0.0, 0.0], [1.5, 0.0], [0.0, 5.0], [0.5, 0.0]]])
    deviation = torch.full((1, 4), 0.5)
    present = torch.tensor([[True, True, True, False]])
    priced = unpriced_in_company(deviation, positions, present, radius=2.0)
    torch.testing.assert_close(priced, torch.tensor([[0.0, 0.0, 0.5, 0.0]]))  # the absent one: only agent 0 near it
    alone = unpriced_in_company(deviation, positions, torch.tensor([[True, False, True, False]]), radius=2.0)
    torch.testing.assert_close(alone, torch.tensor([[0.5, 0.0, 0.5, 0.0]]))  # agent 0 alone once agent 1 left
    assert unpriced_in_company(deviation, positions, present, radius=0.0) is deviation
    assert in_company(positions, present, 2.0).tolist() == [[True, True, False, True]]  # agent 2 alone
    assert not in_company(positions, present, 0.0).any()
    with pytest.raises(ValueError, match=r"^deviation_radius=-1 is invalid: must be a number in \[0, 1000\]"):
        paper_room().room(num_agents=2, deviation_radius=-1)


def test_only_an_oncoming_walker_frees_a_walker_under_the_oncoming_gate():
    """Analytic, in a corridor along x (goals at x = +-20, radius 4 m): A (walking east) and B (1 m ahead of it,
    walking west) meet and deviate for free; C (3.5 m behind A, walking east, B out of its reach) is company under the
    company gate but pays under the oncoming one; once A turns round (walks west) B pays (A ahead of it goes its way)
    and C goes free (A ahead of it comes at it); D, alone, pays under both; a bad gate gets one line."""
    positions = torch.tensor([[[0.0, 0.0], [1.0, 0.0], [-3.5, 0.0], [0.0, 30.0]]])
    east, west = [20.0, 0.0], [-20.0, 0.0]
    targets = torch.tensor([[east, west, east, [0.0, 50.0]]])
    velocities = torch.tensor([[[1.3, 0.0], [-1.3, 0.0], [1.3, 0.0], [0.0, 1.3]]])
    deviation, present = torch.full((1, 4), 0.5), torch.ones(1, 4, dtype=torch.bool)
    company = unpriced_in_company(deviation, positions, present, radius=4.0)
    torch.testing.assert_close(company, torch.tensor([[0.0, 0.0, 0.0, 0.5]]))
    oncoming = unpriced_in_company(deviation, positions, present, radius=4.0, oncoming=(velocities, targets))
    torch.testing.assert_close(oncoming, torch.tensor([[0.0, 0.0, 0.5, 0.5]]))  # C follows A: nobody comes at C
    turned = velocities.clone()
    turned[0, 0] = torch.tensor([-1.3, 0.0])  # A walks west, away from its goal
    after = unpriced_in_company(deviation, positions, present, radius=4.0, oncoming=(turned, targets))
    torch.testing.assert_close(after, torch.tensor([[0.0, 0.5, 0.0, 0.5]]))  # B still comes at A
    with pytest.raises(ValueError, match=r"^deviation_gate='ahead' is invalid: must be one of"):
        paper_room().room(num_agents=2, deviation_gate="ahead")


def test_the_passing_price_finds_an_oncoming_walker_on_the_wrong_side():
    """Analytic, in a corridor along x (radius 4 m, band 0.8 m): A walks east; B, 2 m ahead walking west, is 0.5 m to
    A's left (and A 0.5 m to B's left); C, 3 m ahead walking west, is 1 m to A's right (A 1 m to C's right); D walks
    east 2 m behind A. Under ``either`` A and B pay (0.5 m apart), C does not (1 m); under ``right`` C pays too (A is
    on its right, not its left); under ``left`` A and B pay (each has the other on its left) and C does not; D, with
    nobody coming at it within 4 m, never pays; nor does anyone with the radius 0; once B walks east (its goal still
    west) A stops paying for it and B still pays for A."""
    positions = torch.tensor([[[0.0, 0.0], [2.0, 0.5], [3.0, -1.0], [-2.0, 0.0]]])
    targets = torch.tensor([[[20.0, 0.0], [-20.0, 0.5], [-20.0, -1.0], [20.0, 0.0]]])
    velocities = torch.tensor([[[1.3, 0.0], [-1.3, 0.0], [-1.3, 0.0], [1.3, 0.0]]])
    present = torch.ones(1, 4, dtype=torch.bool)
    expected = {"either": [True, True, False, False], "right": [True, True, True, False],
                "left": [True, True, False, False]}  # fmt: skip
    for side, wrong in expected.items():
        got = wrong_side_passing(positions, velocities, targets, present, 4.0, 0.8, side)
        assert got.tolist() == [wrong], side
    assert not wrong_side_passing(positions, velocities, targets, present, 0.0, 0.8, "right").any()
    turned = velocities.clone()
    turned[0, 1, 0] = 1.3  # B walks east, A's way
    got = wrong_side_passing(positions, turned, targets, present, 4.0, 0.8, "either")
    assert got.tolist() == [[False, True, False, False]]  # A no longer pays for B; A still comes at B
    env = paper_room().room(num_agents=4, reward_passing=-2.0)
    table = env.params.rewards
    flags = torch.zeros(1, 4, dtype=torch.bool)
    priced = compute_rewards(table=table, reached=flags, crashed_wall=flags, crashed_agent=flags,
                             acting=torch.tensor([[True, True, True, False]]),
                             passing=torch.tensor([[True, False, True, True]]))  # fmt: skip
    torch.testing.assert_close(priced, torch.tensor([[-3.0, -1.0, -3.0, 0.0]]))  # the time cost -1, then -2
    with pytest.raises(ValueError, match=r"^passing_side='middle' is invalid: must be one of"):
        paper_room().room(num_agents=2, passing_side="middle")
    with pytest.raises(ValueError, match=r"^passing_band=-1 is invalid: must be a number in \[0, 1000\]"):
        paper_room().room(num_agents=2, passing_band=-1)
    with pytest.raises(ValueError, match=r"^reward_passing=1 is invalid: must be a number in \[-1e\+06, 0\]"):
        RewardTable(passing=1)


@pytest.mark.skipif(not numba_available(), reason="numba")
def test_the_passing_price_is_alike_in_torch_and_in_the_kernel():
    """The twins: passing_kernel is wrong_side_passing, agent by agent, for each side and several radii and bands,
    over random crowds of 2 rooms x 25 agents (some absent, random velocities and goals) and one of 600."""
    env = paper_room(width=10.0, length=12.0).room(num_agents=2, reward_passing=-1.0)
    generator = torch.Generator().manual_seed(0)
    for rooms, agents, size in ((2, 25, 10.0), (1, 600, 60.0)):
        positions = torch.rand(rooms, agents, 2, generator=generator) * size
        present = torch.rand(rooms, agents, generator=generator) < 0.8
        velocities = torch.randn(rooms, agents, 2, generator=generator)
        targets = torch.rand(rooms, agents, 2, generator=generator) * size
        arrays = (positions.numpy(), present.numpy(), velocities.numpy(), targets.numpy())
        for (side_index, side), radius, band in itertools.product(enumerate(PASSING_SIDES), (1.5, 4.0), (0.3, 0.8)):
            room = env.params.kernel_room(env)._replace(
                passing_radius=np.float32(radius), passing_band=np.float32(band), passing_side=side_index
            )
            expected = wrong_side_passing(positions, velocities, targets, present, radius, band, side)
            got = torch.tensor([[passing_kernel(room, r, i, *arrays) for i in range(agents)] for r in range(rooms)])
            assert torch.equal(got, expected), (agents, side, radius, band)
            assert 0 < int(expected.sum()) < int(present.sum()), (agents, side, radius, band)


@pytest.mark.skipif(not numba_available(), reason="numba")
def test_the_deviation_radius_prices_alike_in_torch_and_in_the_kernels():
    """The twins: crowded_kernel is unpriced_in_company's test, agent by agent, under both gates, over random crowds
    of 2 rooms x 25 agents (some absent, random velocities and goals) and radii, and over one of 600; in the compiled
    room a radius that takes in the whole room prices nothing (the rewards of a room without the price), one below any
    gap between bodies prices everything (the rewards of radius 0), with the random draws the same."""
    env = paper_room(width=10.0, length=12.0).room(num_agents=2, reward_deviation=-1.0, deviation_radius=1.0)
    generator = torch.Generator().manual_seed(0)
    positions = torch.rand(2, 25, 2, generator=generator) * 10
    present = torch.rand(2, 25, generator=generator) < 0.8
    velocities, targets = torch.randn(2, 25, 2, generator=generator), torch.rand(2, 25, 2, generator=generator) * 10

    def kernel_unpriced(room, positions, present, velocities, targets):
        arrays = (positions.numpy(), present.numpy(), velocities.numpy(), targets.numpy())
        rooms, agents = present.shape
        return torch.tensor([[crowded_kernel(room, r, i, *arrays) for i in range(agents)] for r in range(rooms)])

    for radius, oncoming in itertools.product((0.5, 1.0, 1.5, 3.0), (False, True)):
        room = env.params.kernel_room(env)._replace(deviation_radius=np.float32(radius), deviation_oncoming=oncoming)
        gate = (velocities, targets) if oncoming else None
        unpriced = unpriced_in_company(torch.ones(2, 25), positions, present, radius, oncoming=gate) == 0
        got = kernel_unpriced(room, positions, present, velocities, targets)
        assert torch.equal(got, unpriced) and 2 < int(unpriced.sum()) < 50, (radius, oncoming)
    # a crowd of 600, where the torch function finds its pairs through grids of cells (pedrl.sim.pairs)
    positions = torch.rand(1, 600, 2, generator=generator) * 60
    present = torch.rand(1, 600, generator=generator) < 0.8
    velocities, targets = torch.randn(1, 600, 2, generator=generator), torch.rand(1, 600, 2, generator=generator) * 60
    for oncoming in (False, True):
        gate = (velocities, targets) if oncoming else None
        unpriced = unpriced_in_company(torch.ones(1, 600), positions, present, 1.5, oncoming=gate) == 0
        room = env.params.kernel_room(env)._replace(deviation_radius=np.float32(1.5), deviation_oncoming=oncoming)
        got = kernel_unpriced(room, positions, present, velocities, targets)
        assert torch.equal(got, unpriced) and 40 < int(unpriced.sum()) < 500, oncoming

    def rewards(deviation: float, radius: float) -> list[torch.Tensor]:
        compiled = CompiledRoom(paper_room(width=10.0, length=12.0).room(
            num_replicas=2, num_agents=12, action_frame="goal", reward_deviation=deviation, deviation_radius=radius,
            speed_ratios=[0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1],
            turn_ratios=[-0.5, -0.25, -0.1, -0.05, 0, 0.05, 0.1, 0.25, 0.5],
        ))  # fmt: skip
        compiled.reset(seed=3)
        generator = torch.Generator().manual_seed(1)
        return [compiled.step(torch.randint(0, 81, (2, 12), generator=generator))[1] for _ in range(6)]

    free, everywhere = rewards(0.0, 0.0), rewards(-2.0, 0.0)
    assert all(torch.equal(a, b) for a, b in zip(rewards(-2.0, 100.0), free, strict=True))
    assert all(torch.equal(a, b) for a, b in zip(rewards(-2.0, 0.01), everywhere, strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(free, everywhere, strict=True))


@pytest.mark.skipif(not numba_available(), reason="numba")
def test_the_kernel_is_the_torch_function_of_one_agent():
    """The twins agree on every combination of flags, with progress, the deviation price and the passing price."""
    env = paper_room(width=10.0, length=12.0).room(
        num_agents=2, reward_goal=100.0, reward_crash_wall=-15.5, reward_crash_agent=-4.25, reward_progress=1.5,
        reward_deviation=-2.5, deviation_turn=0.25, reward_passing=-1.75,
    )  # fmt: skip
    room = env.params.kernel_room(env)
    flags = torch.tensor(list(itertools.product([False, True], repeat=4))).T.reshape(4, 1, 16)
    acting, reached, crashed_wall, crashed_agent = flags
    generator = torch.Generator().manual_seed(0)
    start, end, target = (torch.rand(1, 16, 2, generator=generator) * 10 for _ in range(3))
    progress = torch.hypot(*(start - target).unbind(-1)) - torch.hypot(*(end - target).unbind(-1))
    speed, heading = torch.rand(1, 16, generator=generator) * 2.5, (torch.rand(1, 16, generator=generator) - 0.5) * 6
    deviation = commanded_deviation(speed, heading, start, target, env.params.max_speed, env.params.deviation_turn)
    passing = torch.rand(1, 16, generator=generator) < 0.5
    expected = compute_rewards(
        table=env.params.rewards,
        reached=reached,
        crashed_wall=crashed_wall,
        crashed_agent=crashed_agent,
        acting=acting,
        progress=progress,
        deviation=deviation,
        passing=passing,
    )
    point = lambda values, i: (np.float32(values[0, i, 0]), np.float32(values[0, i, 1]))  # noqa: E731
    got = [
        reward_kernel(
            room, acting[0, i].item(), reached[0, i].item(), crashed_wall[0, i].item(), crashed_agent[0, i].item(),
            point(start, i), point(end, i), point(target, i),
            deviation_kernel(room, np.float32(speed[0, i]), np.float32(heading[0, i]), point(start, i),
                             point(target, i)),
            passing[0, i].item(),
        )
        for i in range(16)
    ]  # fmt: skip
    np.testing.assert_allclose(got, expected[0].numpy(), rtol=0, atol=1e-5)
    assert all(value == 0 for value, on in zip(got, acting[0].tolist(), strict=True) if not on)


def test_a_reward_lives_in_its_record_its_setting_and_its_default():
    """The worked example of a new reward: a field of RewardTable (rewards.py: the record, its term in the torch
    function and in the kernel), the setting reward_<name> of RoomParams (params.py; the kernels read it from
    KernelRoom by that name), its row in docs/configuration.md and its default in conf/env/room.yaml; a reward added
    after checkpoints were written also has the value of their time in pedrl/configs/stored.py. No other module of the
    package names it: the step, its kernel and the room's checks call the reward's functions by name."""
    root = Path(__file__).resolve().parents[2]
    kernel_source = inspect.getsource(getattr(reward_kernel, "py_func", reward_kernel))
    torch_source = inspect.getsource(compute_rewards)
    manual = (root / "docs/configuration.md").read_text()
    for item in dataclasses.fields(RewardTable):
        setting = f"reward_{item.name}"
        naming = {
            str(path.relative_to(root))
            for path in (root / "pedrl").rglob("*.py")
            if re.search(rf"\b{setting}\b", path.read_text())
        }
        assert naming - {"pedrl/configs/stored.py"} == {"pedrl/sim/rewards.py", "pedrl/sim/params.py"}, naming
        assert setting in RoomParams.__dataclass_fields__ and f"| `{setting}` |" in manual, setting
        assert re.search(rf"^{setting}:", (root / "conf/env/room.yaml").read_text(), re.MULTILINE), setting
        assert f"room.{setting}" in kernel_source and f"table.{item.name}" in torch_source, setting
