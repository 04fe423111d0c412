"""A PettingZoo ``ParallelEnv`` over one replica of :class:`~pedrl.sim.RoomEnv`.

Usage::

    from pedrl.integrations.pettingzoo import parallel_env

    env = parallel_env(num_agents=5, width=6.0, length=8.0, door_width=1.5, max_decisions=30)
    obs, infos = env.reset(seed=0)
    while env.agents:
        actions = {agent: env.action_space(agent).sample() for agent in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)

The adapter adds nothing to the simulation: its observations, rewards and flags are those of ``RoomEnv`` for
replica 0, converted to numpy float32 arrays and Python floats and bools. An agent is in ``agents`` while it is in
its trial; the step in which it reaches the door (``terminations``) or the trial clock reaches ``max_decisions``
(``truncations``) is the last one that reports it. Needs ``pip install pedrl[pettingzoo]``.
"""

from __future__ import annotations

import inspect
import math
import operator
import warnings
from collections.abc import Mapping
from dataclasses import fields
from typing import Any, Final

import numpy as np
import torch

try:
    import gymnasium
    from gymnasium import spaces
    from pettingzoo import ParallelEnv
except ImportError as error:  # one line naming the fix, the cause chained
    raise ImportError(
        f"pedrl.integrations.pettingzoo needs pettingzoo and gymnasium ({error}): pip install pedrl[pettingzoo]"
    ) from error

from pedrl.common.checks import check_integer, check_number
from pedrl.rl.neural import ContinuousPolicy, NeuralPolicy
from pedrl.rl.policy import TabularPolicy
from pedrl.sim import NOOP_ACTION, RoomEnv, commands_of

__all__ = ["REGISTRY_ID", "PedestrianParallelEnv", "make_env", "parallel_env", "register"]

AGENT_PREFIX: Final = "pedestrian_"
INFO_KEYS: Final = ("crashed_agent", "crashed_wall", "reached", "speed", "num_sensed", "neighbour_velocity")
"""Per-agent info keys, taken from ``RoomEnv``'s info for the agent (``num_sensed``: the neighbours in its
observation, the second input of an ONNX model of ``pedrl-export``)."""
REGISTRY_ID: Final = "pedrl/room_v0"
"""The id under which importing this module registers :func:`make_env` in PettingZoo's registry of parallel
environments (PettingZoo 1.27 on): ``pettingzoo.make("parallel", "pedrl/room_v0", num_agents=5)``."""
PLACEMENT_OPTIONS: Final = {"positions": 2, "headings": 1, "speeds": 1}
"""``reset`` options passed to ``RoomEnv.reset``, with the number of axes of one replica's value."""
BOUND_SLACK: Final = 1e-5
"""Relative widening of the bounds that float32 rounding could reach (distances, relative speeds, velocities)."""


def _widen(value: float) -> float:
    return value * (1.0 + BOUND_SLACK)


def observation_bounds(env: RoomEnv) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds ``(F,)`` float32 of every feature of ``env``, from the feature names.

    Own speed in ``[0, max_speed]``; angles in ``[-pi, pi]`` (``RoomEnv`` wraps them to ``(-pi, pi]``); relative
    speeds in ``[-2 max_speed, 2 max_speed]``; the distance to the goal point in ``[0, max_distance + goal_depth]``
    (the goal point lies ``goal_depth`` behind the door, on the room's boundary); other distances (neighbours,
    walls: both ends in the room) in ``[0, max_distance]``, the room diagonal. The bounds that rounding could reach
    are widened by ``BOUND_SLACK``; a feature of unknown kind gets ``(-inf, inf)``. Inactive agents' zeros are
    inside every bound.
    """
    max_speed = float(env.params.max_speed)
    max_distance = float(env.max_distance)
    goal_depth = float(env.params.goal_depth)
    low, high = [], []
    for name in env.feature_names:
        if name == "speed":
            bounds = (0.0, max_speed)  # clamped to max_speed in float32: exact
        elif name.endswith("_angle"):
            bounds = (-math.pi, math.pi)  # float32 pi is above pi, and the wrap never exceeds it
        elif name.endswith("_rel_speed"):
            bounds = (-_widen(2.0 * max_speed), _widen(2.0 * max_speed))
        elif name == "door_distance":
            bounds = (0.0, _widen(max_distance + goal_depth))
        elif name.endswith("_distance"):
            bounds = (0.0, _widen(max_distance))
        else:
            bounds = (-math.inf, math.inf)
        low.append(bounds[0])
        high.append(bounds[1])
    return np.asarray(low, dtype=np.float32), np.asarray(high, dtype=np.float32)


class PedestrianParallelEnv(ParallelEnv):
    """PettingZoo ``ParallelEnv`` over a ``RoomEnv`` with one replica: one room, ``num_agents`` pedestrians.

    Agents are ``"pedestrian_0"`` .. ``"pedestrian_{N-1}"``, agent ``i`` being the room's agent ``i``. Each
    observes ``RoomEnv``'s ``num_features`` deictic features (``feature_names``) as a float32 array, and picks one
    of the 81 actions (``Discrete(81)``; in the paper's ``heading`` action frame ``pedrl.sim.NOOP_ACTION`` keeps speed
    and heading, in the ``goal`` frame it walks at ``speed_ratios[4]`` of the top speed straight at the goal).

    ``step`` semantics, for a dict of actions keyed by agent:

    - an agent of ``agents`` missing from the dict takes ``NOOP_ACTION``: in the ``heading`` frame it keeps its speed
      and heading, as a pedestrian that decides nothing new would;
    - actions for agents that already left ``agents`` are ignored (``RoomEnv`` ignores inactive agents); an
      unknown agent name or an action outside ``[0, 81)`` is a ``ValueError``;
    - the returned dicts are keyed by the agents active before the step; those that reached the door
      (``terminations``, observation 0) or ran out of time (``truncations``) leave ``agents`` afterwards;
    - infos hold ``crashed_agent``, ``crashed_wall``, ``reached`` (bools), ``speed`` (m/s after the step),
      ``num_sensed`` (int: the neighbours the observation holds, which an ONNX model of ``pedrl-export`` reads beside
      it) and ``neighbour_velocity`` (``(k, 2)`` float32: their velocities in the goal frame, the third input of a
      model trained with ``algo.neighbour_velocity=true``);
    - with no agent left, ``step`` returns empty dicts and does not advance the room.

    ``reset(seed, options)`` reseeds the room's generator when ``seed`` is given; ``options`` may hold one
    replica's hand placement, ``positions`` ``(N, 2)`` (m), ``headings`` ``(N,)`` (rad) and ``speeds`` ``(N,)``
    (m/s), as ``RoomEnv.reset`` takes them (a leading replica axis of 1 is accepted too). Other option keys are
    ignored with a warning (PettingZoo's API test passes arbitrary ones).

    A learned crowd (``crowd``, a :class:`pedrl.rl.TabularPolicy` or a network's :class:`pedrl.rl.NeuralPolicy`, a
    continuous one's included, e.g. ``pedrl.load_policy(path)``) drives every agent but the first ``learners``: only
    ``pedestrian_0 .. pedestrian_{learners-1}`` are PettingZoo agents, and the others act with ``crowd.act``
    (exploration ``crowd_epsilon``, drawn from a generator that ``reset(seed)`` reseeds), so that a user's own learner
    trains among a learned crowd. The episode ends for the caller when none of its agents is left, even if crowd
    agents still walk.

    ``state()`` is the global state for centralised training: the positions (m) then the velocities (m/s) of all
    ``N`` agents, ``(4 N,)`` float32 as ``[x0, y0, x1, y1, ..., vx0, vy0, ...]``, zero for agents not in ``agents``.

    The room may live on any device: its tensors are copied to the CPU once per call.

    Args:
        env: A built ``RoomEnv`` with ``num_replicas == 1``; the adapter resets and steps it.
        render_mode: Only ``None``: nothing is rendered (``pedrl-eval`` draws animations of whole trials).
        crowd: A learned policy for the agents after the first ``learners`` (None: every agent is the caller's).
        learners: The caller's agents, in ``[1, num_agents]`` (default: all of them, or 1 with a ``crowd``).
        crowd_epsilon: Share of random actions of the crowd, in ``[0, 1]``.

    Raises:
        ValueError: If ``env.num_replicas`` is not 1, ``render_mode`` is not ``None``, ``learners`` is out of range,
            or ``crowd`` reads other observations than the room gives.
    """

    metadata: dict[str, Any] = {"name": "pedrl_room_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(
        self,
        env: RoomEnv,
        *,
        render_mode: str | None = None,
        crowd: TabularPolicy | None = None,
        learners: int | None = None,
        crowd_epsilon: float = 0.0,
    ) -> None:
        num_replicas = getattr(env, "num_replicas", None)
        if num_replicas != 1:
            raise ValueError(
                f"env.num_replicas={num_replicas!r} is invalid: PedestrianParallelEnv wraps one room, build"
                " RoomEnv(num_replicas=1, ...)"
            )
        if render_mode is not None:
            raise ValueError(f"render_mode={render_mode!r} is invalid: PedestrianParallelEnv supports only None")
        learners = (1 if crowd is not None else env.num_agents) if learners is None else learners
        check_integer("learners", learners, minimum=1, maximum=env.num_agents)
        check_number("crowd_epsilon", crowd_epsilon, low=0.0, high=1.0)
        if crowd is not None and not isinstance(crowd, TabularPolicy | NeuralPolicy):
            raise ValueError(
                f"crowd of type {type(crowd).__name__} is invalid: must be a pedrl.TabularPolicy or NeuralPolicy "
                "(pedrl.load_policy)"
            )
        if crowd is not None and crowd.device != env.device:
            raise ValueError(
                f"crowd is on {crowd.device} and the room on {env.device}: load it there, "
                f"pedrl.load_policy(path, device={str(env.device)!r})"
            )
        if isinstance(crowd, ContinuousPolicy) and env.params.action_frame != "goal":
            raise ValueError(
                f"crowd is a continuous policy and the room's env.action_frame={env.params.action_frame!r}: its "
                "commands need the goal frame (a room of its own config, pedrl.policy_files.room_factory)"
            )
        if crowd is not None:
            features = crowd.encoder.settings.num_features
            discrete = not isinstance(crowd, ContinuousPolicy)
            if features != env.num_features or (discrete and crowd.num_actions != env.num_actions):
                raise ValueError(
                    f"crowd reads {features} features and has {crowd.num_actions} actions: the room gives "
                    f"{env.num_features} features and {env.num_actions} actions (num_neighbours, num_walls)"
                )
        self.env = env
        self.render_mode = render_mode
        self.crowd, self.crowd_epsilon = crowd, float(crowd_epsilon)
        self._crowd_generator = torch.Generator(device=env.device)
        self._last: tuple[torch.Tensor, Mapping[str, Any]] | None = None
        self.possible_agents: list[str] = [f"{AGENT_PREFIX}{index}" for index in range(learners)]
        self.agents: list[str] = []
        self._index = {agent: index for index, agent in enumerate(self.possible_agents)}
        low, high = observation_bounds(env)
        # one object per agent, always the same one (PettingZoo seeds and caches spaces per agent)
        self.observation_spaces = {
            agent: spaces.Box(low=low, high=high, dtype=np.float32) for agent in self.possible_agents
        }
        self.action_spaces = {agent: spaces.Discrete(env.num_actions) for agent in self.possible_agents}
        max_velocity = _widen(float(env.params.max_speed))
        num_agents = env.num_agents
        state_low = np.concatenate((np.full(2 * num_agents, -np.inf), np.full(2 * num_agents, -max_velocity))).astype(
            np.float32
        )
        self.state_space = spaces.Box(low=state_low, high=-state_low, dtype=np.float32)
        self._was_reset = False

    # ------------------------------------------------------------------ spaces

    def observation_space(self, agent: str) -> spaces.Box:
        """``Box(float32, (num_features,))`` of ``agent``, the same object at every call."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Discrete:
        """``Discrete(81)`` of ``agent``, the same object at every call."""
        return self.action_spaces[agent]

    # ------------------------------------------------------------------ API

    def reset(
        self, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start a new trial: every agent in ``agents``; returns the observations and infos of all of them."""
        obs, info = self.env.reset(seed=seed, options=self._room_options(options))
        if seed is not None:
            self._crowd_generator.manual_seed(seed)
        self._last = (obs, info)
        self._was_reset = True
        active = self.env.active[0].cpu().tolist()[: len(self.possible_agents)]
        self.agents = [agent for agent, alive in zip(self.possible_agents, active, strict=True) if alive]
        indices = list(range(len(self.possible_agents)))
        return self._observations(obs, indices), self._infos(info, indices)

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        """Advance the room one decision (see the class docstring for missing and extra actions)."""
        if not self._was_reset:
            raise RuntimeError("PedestrianParallelEnv.step() called before reset()")
        room_actions = self._room_actions(actions)
        acting = [self._index[agent] for agent in self.agents]
        if not acting:
            return {}, {}, {}, {}, {}
        if self.crowd is not None:
            crowd = self.crowd.act(*self._last, epsilon=self.crowd_epsilon, generator=self._crowd_generator).cpu()
            if crowd.is_floating_point():  # a continuous crowd: the learners' actions as the commands they are
                changes = dict(speed_changes=self.env.speed_changes.cpu(), turn_changes=self.env.turn_changes.cpu())
                room_actions = commands_of(room_actions, **changes, max_speed=self.env.params.max_speed)
            room_actions[0, len(self.possible_agents) :] = crowd[0, len(self.possible_agents) :]
        obs, reward, terminated, truncated, info = self.env.step(room_actions)
        self._last = (obs, info)
        rewards = reward[0].cpu().tolist()
        terminations = terminated[0].cpu().tolist()
        truncations = truncated[0].cpu().tolist()
        names = [self.possible_agents[index] for index in acting]
        result = (
            self._observations(obs, acting),
            {agent: float(rewards[index]) for agent, index in zip(names, acting, strict=True)},
            {agent: bool(terminations[index]) for agent, index in zip(names, acting, strict=True)},
            {agent: bool(truncations[index]) for agent, index in zip(names, acting, strict=True)},
            self._infos(info, acting),
        )
        self.agents = [
            agent for agent, index in zip(names, acting, strict=True) if not (terminations[index] or truncations[index])
        ]
        return result

    def state(self) -> np.ndarray:
        """Positions then velocities of all agents, ``(4 N,)`` float32, zero for agents not in ``agents``."""
        active = self.env.active[0].unsqueeze(-1)
        positions = torch.where(active, self.env.positions[0], 0.0)
        velocities = torch.where(active, self.env.velocities[0], 0.0)
        return torch.cat((positions.flatten(), velocities.flatten())).to(torch.float32).cpu().numpy()

    def render(self) -> None:
        """Nothing to render (``render_mode`` is ``None``)."""
        gymnasium.logger.warn("PedestrianParallelEnv.render() does nothing: it supports only render_mode=None")

    def close(self) -> None:
        """Nothing to release."""

    # ------------------------------------------------------------------ conversions

    def _room_options(self, options: Mapping[str, Any] | None) -> dict[str, torch.Tensor]:
        """One replica's placement options with the replica axis added; other keys ignored with a warning."""
        options = dict(options or {})
        ignored = sorted(repr(key) for key in options if key not in PLACEMENT_OPTIONS)
        if ignored:
            warnings.warn(
                f"PedestrianParallelEnv.reset ignores the options {', '.join(ignored)}: it takes"
                f" {', '.join(PLACEMENT_OPTIONS)}",
                UserWarning,
                stacklevel=3,
            )
        room_options = {}
        for key, axes in PLACEMENT_OPTIONS.items():
            if options.get(key) is None:
                continue
            value = torch.as_tensor(np.asarray(options[key], dtype=np.float32))
            room_options[key] = value.unsqueeze(0) if value.dim() == axes else value  # RoomEnv checks the shape
        return room_options

    def _room_actions(self, actions: Mapping[str, Any]) -> torch.Tensor:
        """Actions ``(1, N)`` int64: the given ones, the no-op for the others (inactive agents' are ignored)."""
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions of type {type(actions).__name__} is invalid: must be a dict keyed by agent")
        room_actions = torch.full((1, self.env.num_agents), NOOP_ACTION, dtype=torch.int64)
        num_actions = self.env.num_actions
        for agent, action in actions.items():
            index = self._index.get(agent)
            if index is None:
                last = self.possible_agents[-1]
                raise ValueError(f"actions key {agent!r} is invalid: must be one of pedestrian_0 .. {last}")
            try:  # a bool is no action: True would be taken as action 1
                value = None if _is_bool(action) else operator.index(action)
            except TypeError:
                value = None
            if value is None or not 0 <= value < num_actions:
                raise ValueError(f"actions[{agent!r}]={action!r} is invalid: must be an integer in [0, {num_actions})")
            room_actions[0, index] = value
        return room_actions

    def _observations(self, obs: torch.Tensor, indices: list[int]) -> dict[str, np.ndarray]:
        rows = obs[0].to(torch.float32).cpu().numpy()
        return {self.possible_agents[index]: rows[index].copy() for index in indices}

    def _infos(self, info: Mapping[str, Any], indices: list[int]) -> dict[str, dict[str, Any]]:
        columns = {key: info[key][0].cpu().tolist() for key in INFO_KEYS}
        infos = {}
        for index in indices:
            values = {key: columns[key][index] for key in INFO_KEYS}
            infos[self.possible_agents[index]] = {
                "crashed_agent": bool(values["crashed_agent"]),
                "crashed_wall": bool(values["crashed_wall"]),
                "reached": bool(values["reached"]),
                "speed": float(values["speed"]),
                "num_sensed": int(values["num_sensed"]),
                "neighbour_velocity": np.asarray(values["neighbour_velocity"], np.float32),  # (k, 2)
            }
        return infos


def _is_bool(value: Any) -> bool:
    """Whether ``value`` is a Python, numpy or torch boolean (a scalar of them)."""
    if isinstance(value, bool | np.bool_):
        return True
    return isinstance(value, torch.Tensor | np.ndarray) and value.dtype in (torch.bool, np.bool_)


RUN_KEYWORDS: Final = ("num_agents", "max_decisions", "device")
"""Keywords of :func:`parallel_env` that say how to run a room, not which room: with a ``crowd`` and none but these,
the room is the crowd's own."""
IGNORED_SETTINGS: Final = ("max_decisions", "compile_sensing")
"""Room settings in which a given room may differ from the crowd's training room without a warning: the trial's
length and how sensing is computed."""


def parallel_env(
    *,
    render_mode: str | None = None,
    scenario: str | dict[str, Any] | None = None,
    crowd: TabularPolicy | None = None,
    learners: int | None = None,
    crowd_epsilon: float = 0.0,
    **room_kwargs: Any,
) -> PedestrianParallelEnv:
    """Build a room of one replica in ``scenario`` (:meth:`pedrl.scenarios.Scenario.room`) and wrap it in a
    :class:`PedestrianParallelEnv`.

    With a ``crowd`` that holds its training config and no room given (no ``scenario``, no room keyword but
    :data:`RUN_KEYWORDS`), the room is the crowd's own (:func:`pedrl.policy_files.room_factory`: its area, bodies,
    speeds, sensing and motion). A room given that differs from it gets one ``UserWarning`` line naming what differs.

    Args:
        render_mode: Only ``None``.
        scenario: A scenario name of :data:`pedrl.scenarios.SCENARIOS` or a ``scenario`` config (``{"name": ...,
            ...}``); ``None``: the paper's room of ``width``, ``length`` and ``door_width`` (or the crowd's own room).
        crowd, learners, crowd_epsilon: a learned crowd for the agents after the first ``learners`` (see
            :class:`PedestrianParallelEnv`).
        **room_kwargs: The room's keywords (``num_agents``, ``max_decisions``, ``device``...), and the paper's room's
            ``width``, ``length`` and ``door_width``.

    Raises:
        ValueError: For an invalid room keyword or scenario (one-line messages) or ``num_replicas`` other than 1.
    """
    from pedrl.configs import room_keywords
    from pedrl.policy_files import room_factory
    from pedrl.scenarios import Scenario, build_scenario

    trained_in = isinstance(crowd, TabularPolicy | NeuralPolicy) and crowd.metadata.get("config") is not None
    if trained_in and scenario is None and set(room_kwargs) <= set(RUN_KEYWORDS):
        factory = room_factory(crowd, max_decisions=room_kwargs.get("max_decisions"))
        agents = room_kwargs.get("num_agents", inspect.signature(Scenario.room).parameters["num_agents"].default)
        room = factory(num_replicas=1, num_agents=agents, device=room_kwargs.get("device", "cpu"))
    else:
        built = build_scenario({"name": scenario} if isinstance(scenario, str) else scenario, room=room_kwargs)
        room = built.room(**{"num_replicas": 1, **room_keywords(room_kwargs)})
        if trained_in:
            _warn_other_room(room, room_factory(crowd)(num_replicas=1, num_agents=1, device=room.device))
    return PedestrianParallelEnv(
        room, render_mode=render_mode, crowd=crowd, learners=learners, crowd_epsilon=crowd_epsilon
    )


def _warn_other_room(room: RoomEnv, own: RoomEnv) -> None:
    """One ``UserWarning`` line when ``room`` differs from the crowd's training room ``own`` beyond
    :data:`IGNORED_SETTINGS`: the settings that differ (the walkable area as one)."""
    differ = [
        item.name
        for item in fields(room.params)
        if item.name not in IGNORED_SETTINGS and getattr(room.params, item.name) != getattr(own.params, item.name)
    ]
    area, trained = room.geometry, own.geometry
    same_area = area.name == trained.name and all(
        a.shape == b.shape and torch.equal(a.cpu(), b.cpu())
        for a, b in ((area.walls[: area.num_walls], trained.walls[: trained.num_walls]), (area.exits, trained.exits))
    )
    if not same_area:
        differ.insert(0, "the walkable area")
    if differ:
        warnings.warn(
            f"crowd was trained in another room: {', '.join(differ)} differ; parallel_env(crowd=...) with no room"
            " keywords but num_agents, max_decisions and device builds its own (pedrl.room_factory(crowd))",
            UserWarning,
            stacklevel=3,
        )


def make_env(*, max_cycles: int | None = None, **kwargs: Any) -> PedestrianParallelEnv:
    """:func:`parallel_env` as PettingZoo's registry calls it: ``max_cycles`` (PettingZoo's name for an episode's
    length, which ``pettingzoo.make`` passes) is the room's ``max_decisions``.

    Raises:
        ValueError: If ``max_cycles`` and ``max_decisions`` are both given and differ (one line).
    """
    if max_cycles is not None:
        given = kwargs.get("max_decisions")
        if given is not None and given != max_cycles:
            raise ValueError(
                f"max_cycles={max_cycles!r} and max_decisions={given!r} disagree: give one of them (max_cycles is"
                " PettingZoo's name for the room's max_decisions)"
            )
        kwargs["max_decisions"] = max_cycles
    return parallel_env(**kwargs)


def register() -> bool:
    """Register :func:`make_env` under :data:`REGISTRY_ID` in PettingZoo's registry of parallel environments, once;
    run when this module is imported. Returns whether PettingZoo has a registry (``pettingzoo.register``, from 1.27
    on); before it, ``parallel_env`` is the way in."""
    import pettingzoo

    if not all(hasattr(pettingzoo, name) for name in ("register", "spec")):
        return False
    from pettingzoo.env_registry.exceptions import PettingZooRegistryError

    try:
        pettingzoo.spec("parallel", REGISTRY_ID)  # registered already (a second import, a reload)
    except PettingZooRegistryError:
        pettingzoo.register("parallel", REGISTRY_ID, entry_point=f"{__name__}:make_env")
    return True


register()
