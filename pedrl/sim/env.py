"""``RoomEnv``: R independent replicas of the room with N agents each, stepped together (pure torch).

The API follows PettingZoo's ``ParallelEnv`` in batched tensor form, over ``[replicas, agents, ...]``:
``reset(seed, options) -> (obs, info)`` and ``step(actions) -> (obs, reward, terminated, truncated, info)``.
Who starts where and heads where (placement, exits, waypoint routes) is :class:`~pedrl.sim.spawning.Spawns`'s
(spawning.py); the checks of the settings, arguments, options and actions are in room_checks.py.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any, Final

import torch

from pedrl._numba import numba_available
from pedrl.common.checks import (
    check_device,
    check_integer,
    check_memory,
)
from pedrl.sim.actions import (
    NUM_ACTIONS,
    apply_actions,
    apply_commands,
    velocities_from,
)
from pedrl.sim.geometry import Geometry, X, Y, extent, spawn_counts
from pedrl.sim.motion import (
    Motion,
    MotionModel,
    Movement,
    SlidingMotion,
    move_agents,
    move_agents_sequential,
    move_agents_sliding,
)
from pedrl.sim.params import RoomParams
from pedrl.sim.rewards import commanded_deviation, compute_rewards, unpriced_in_company, wrong_side_passing
from pedrl.sim.room_checks import (
    check_actions,
    check_area,
    read_option,
    read_options,
    step_memory,
)
from pedrl.sim.sensing import Observation, compiled_observe, feature_names, num_features, observe
from pedrl.sim.spawning import MAX_DENSITY as MAX_DENSITY  # re-exported: pedrl.scenarios checks its spawn areas by it
from pedrl.sim.spawning import PlacementError as PlacementError  # re-exported: raised by reset
from pedrl.sim.spawning import Spawns, check_density
from pedrl.sim.state import RoomState

MAX_PLACEMENT_ROUNDS: Final = 1000
"""Rounds of rejection sampling before placement gives up (:meth:`Spawns.place <pedrl.sim.spawning.Spawns.place>`)."""
MAX_RESET_SEED: Final = 2**64 - 1
"""Largest ``reset(seed=...)``: a torch generator's seed is 64 bits. Wider than the command line's ``seed``
(``MAX_SEED``, 2^32 - 1), because trainers and evaluation reseed rooms with derived seeds such as
``seed * 10007 + phase``."""


class RoomEnv:
    """R replicas of a walkable area (a scenario's, compiled), each holding N agents that must leave by an exit.

    Every replica and agent shares one trial clock (paper section 5): an agent's trial ends when it reaches
    the door (``terminated``) or when its replica's clock reaches ``max_decisions`` (``truncated``); it is
    then inactive: it no longer moves, collides, is sensed or acts, and gets obs 0 and reward 0. A partial
    reset (``options["replicas"]``) restarts the clock of the reset replicas only.

    Attributes:
        positions: Agent centres ``(R, N, 2)`` (m).
        velocities: Velocities ``(R, N, 2)`` (m/s), ``speeds * (cos headings, sin headings)``.
        headings: Headings ``(R, N)`` (rad, world frame, in ``(-pi, pi]``).
        speeds: Speeds ``(R, N)`` (m/s, in ``[0, max_speed]``); frozen once an agent is inactive.
        active: Agents still in their trial ``(R, N)`` bool.
        params: The room's settings (:class:`~pedrl.sim.params.RoomParams`), with what the fast path supports: read
            them there (``room.params.max_speed``; ``params.rewards`` is their reward table, ``params.substep`` the
            longest move per sub-step, ``params.decision_length`` a decision's duration). The room keeps only what is
            its own: the batch, the built area and tables, the state, and the motion model (:attr:`motion`).
        state: The rooms' state (:class:`~pedrl.sim.state.RoomState`); :meth:`load_state` sets it.
        geometry: The walkable area: walls, exits, spawn areas and routes (:class:`~pedrl.sim.geometry.Geometry`),
            on ``device``, its goal points at ``goal_depth``.
        motion: The motion model (:class:`~pedrl.sim.motion.MotionModel`: ``Stop``, ``Slide``, ``Yield`` ...),
            ``params.motion`` (read-only).
        motion_constants: The constants of a decision's movement under it (:class:`~pedrl.sim.motion.Motion`).
        exit_index: The exit each agent heads for ``(R, N)`` int64: its group's, or the nearest at placement.
        stage: The waypoint each agent aims at ``(R, N)`` int64; past its group's waypoints, its exit.
        spawns: Who starts where and heads where (:class:`~pedrl.sim.spawning.Spawns`).
        spawn_counts: The number of agents of each spawn group (agents numbered group by group).
        generator: The environment's random generator, on ``device``; ``reset(seed=...)`` reseeds it.
        num_actions: 81.
        num_features: ``3 + 3 * num_neighbours + 2 * num_walls``.
        feature_names: Names of the features in layout order.
        num_substeps: Sub-steps per decision.
        speed_changes: The speed change (m/s) of each speed index, ``speed_ratios * max_speed``, on ``device``.
        turn_changes: The heading change (rad) of each turn index, ``turn_ratios * pi``, on ``device``.
    """

    num_actions: Final = NUM_ACTIONS

    def __init__(
        self,
        area: Geometry,
        params: RoomParams | None = None,
        *,
        num_replicas: int = 1,
        num_agents: int = 20,
        device: str | torch.device = "cpu",
    ) -> None:
        """Check the room against its area and allocate the state (call :meth:`reset` before :meth:`step`).

        Args:
            area: The walkable area, compiled (:class:`~pedrl.sim.geometry.Geometry`): a scenario's
                (``pedrl.scenarios``; ``Scenario.room(...)`` compiles it and builds a room in one call, the paper's
                room with ``pedrl.scenarios.paper_room``); its goal points are moved to ``params.goal_depth``.
            params: The room's settings (:class:`~pedrl.sim.params.RoomParams`, checked when they were made; None:
                the defaults), kept as :attr:`params` (``room.params.max_speed``).
            num_replicas: Number R of independent rooms stepped together.
            num_agents: Number N of agents per room.
            device: Torch device of every tensor.

        Raises:
            ValueError: With a one-line message naming the bad value, for any invalid argument, including settings
                the area cannot hold (a body wider than an exit, more sensed walls than it has) and more agents than
                fit in it.
        """
        # ---- validation: every check before any compute
        params = RoomParams() if params is None else params
        if not isinstance(params, RoomParams):
            raise ValueError(
                f"params of type {type(params).__name__} is invalid: must be a pedrl.sim.RoomParams (e.g."
                " RoomParams(max_speed=1.34)); Scenario.room(...) takes the settings as keywords"
            )
        self.num_replicas = check_integer("num_replicas", num_replicas, minimum=1)
        self.num_agents = check_integer("num_agents", num_agents, minimum=1)
        self.device = check_device(device)
        check_area(area, params.agent_radius)
        check_integer("num_walls", params.num_walls, minimum=0, maximum=area.num_walls)
        self.params = params
        self._build(self._checked_room(area))

    def _checked_room(self, area: Geometry) -> Geometry:
        """The walkable area with its goal points at ``goal_depth``, and the checks that need it: the agents fit in
        the spawn areas, the sub-steps and the memory of a decision."""
        if area.goal_depth != self.params.goal_depth:
            area = replace(area, goal_depth=self.params.goal_depth)
        self.spawn_counts = spawn_counts(self.num_agents, [spawn.weight for spawn in area.spawns])
        check_density(
            area, self.spawn_counts, self.num_agents, agent_radius=self.params.agent_radius, room=extent(area)
        )
        self.num_substeps = self.params.num_substeps
        check_memory(
            {"room state and collision pairs": self.step_memory()},
            device=self.device,
            advice="fewer agents or replicas (processes, rooms_per_process, trials_per_batch)",
        )
        self._torch_memory_checked = False
        return area

    def _build(self, geometry: Geometry) -> None:
        """The constants (geometry on the device, spawn tables, action tables), the generator and the state, zero
        until :meth:`reset`."""
        self.geometry = geometry if geometry.device == self.device else geometry.to(self.device)
        self.spawns = Spawns(
            self.geometry,
            self.spawn_counts,
            agent_radius=self.params.agent_radius,
            num_replicas=self.num_replicas,
            room=extent(geometry),
            device=self.device,
        )
        constants = (self.geometry, self.params.agent_radius, self.params.decision_length, self.num_substeps)
        model = self.motion
        self.motion_constants = (
            Motion(*constants)
            if model.contact == "stop"
            else SlidingMotion(*constants, model.time_gap, model.contact == "yield", model.steering)
        )
        self.speed_changes = torch.tensor(self.params.speed_ratios, device=self.device) * self.params.max_speed
        self.turn_changes = torch.tensor(self.params.turn_ratios, device=self.device) * math.pi
        self.num_features = num_features(self.params.num_neighbours, self.params.num_walls)
        self.feature_names = feature_names(self.params.num_neighbours, self.params.num_walls)
        self.generator = torch.Generator(device=self.device)
        self.generator.seed()

        # ---- state (filled by reset)
        shape = (self.num_replicas, self.num_agents)
        self.positions = torch.zeros(*shape, 2, device=self.device)
        self.velocities = torch.zeros(*shape, 2, device=self.device)
        self.headings = torch.zeros(shape, device=self.device)
        self.speeds = torch.zeros(shape, device=self.device)
        self.active = torch.zeros(shape, dtype=torch.bool, device=self.device)
        self.exit_index = torch.zeros(shape, dtype=torch.int64, device=self.device)
        self.stage = torch.zeros(shape, dtype=torch.int64, device=self.device)
        self._targets = torch.zeros(*shape, 2, device=self.device)
        self.decisions = torch.zeros(self.num_replicas, dtype=torch.int64, device=self.device)
        self._steps_taken = 0
        self._reset_at = torch.zeros(self.num_replicas, dtype=torch.int64)  # host: _steps_taken at each reset
        self._oldest_reset = 0
        self._was_reset = False

    def targets(self) -> torch.Tensor:
        """The point each agent aims at ``(R, N, 2)`` (m): its current waypoint, else its exit's goal point. The
        reference line of the state and the progress reward run to it. Set at reset and when routes advance."""
        return self._targets

    def fast_path_reason(self) -> str | None:
        """Why the fast path (the fused numba trial) cannot step this room (one phrase), or None when it can: on
        another device than the CPU, a setting :class:`~pedrl.sim.params.RoomParams` does not declare it supports,
        or the motion model ``Stop`` in a room whose walls are not all axis-aligned (its kernel clamps to wall
        boxes)."""
        if self.device.type != "cpu":
            return f"on {self.device.type}: it runs on the CPU"
        reason = self.params.fast_path_reason()
        if reason is None and self.motion.contact == "stop" and not self.geometry.axis_aligned:
            return "with motion=stop in a room whose walls are not all axis-aligned"
        return reason

    @property
    def state(self) -> RoomState:
        """The rooms' state (:class:`~pedrl.sim.state.RoomState`): views of the env's tensors, not copies."""
        return RoomState(
            self.positions, self.velocities, self.headings, self.speeds, self.active, self.exit_index,
            self._targets, self.decisions, self.stage,
        )  # fmt: skip

    def load_state(self, state: RoomState, *, decisions_taken: int = 0) -> None:
        """Take ``state`` as the rooms' state (its tensors, not copies), as after ``decisions_taken`` more decisions
        of the trial clock (a kernel that ran them); ``ValueError`` for a tensor of another shape, dtype or device.

        Args:
            state: The new state, shaped as :attr:`state`.
            decisions_taken: Decisions the trial clock advances by (``>= 0``).
        """
        state.check_like(self.state)
        taken = check_integer("decisions_taken", decisions_taken, minimum=0)
        self.positions, self.velocities, self.headings, self.speeds = (
            state.positions,
            state.velocities,
            state.headings,
            state.speeds,
        )
        self.active, self.exit_index, self._targets = state.active, state.exit_index, state.targets
        self.decisions, self.stage = state.decisions, state.stage
        self._steps_taken += taken

    def _advance_routes(self) -> None:
        """Agents that reached their waypoint aim at the next point of their route (:meth:`Spawns.advance`)."""
        if self.spawns.has_routes:
            self.stage, self._targets = self.spawns.advance(self.positions, self.stage, self.exit_index)

    def step_memory(self, *, kernels: bool | None = None) -> int:
        """Estimated peak bytes of one decision (:func:`~pedrl.sim.room_checks.step_memory`): of the fused trial's
        kernels (linear in the agents) or of :meth:`step` (``kernels=False``, every pair); None: the kernels' where
        they can run this room (on the CPU with numba)."""
        if kernels is None:
            kernels = self.device.type == "cpu" and numba_available() and self.params.fast_path_reason() is None
        return step_memory(self.num_replicas, self.num_agents, self.num_substeps, self.motion.rule, kernels=kernels)

    # ------------------------------------------------------------------ public API

    @property
    def decision(self) -> int:
        """The trial clock: decisions since the reset of the replica reset longest ago (all, usually)."""
        return self._steps_taken - self._oldest_reset

    @property
    def motion(self) -> MotionModel:
        """The motion model, ``params.motion``."""
        return self.params.motion

    @property
    def max_distance(self) -> float:
        """The room diagonal (m): no two points of the room are further apart (for ``fill_void_neighbours``)."""
        return self.geometry.diagonal

    def reset(
        self, *, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[torch.Tensor, dict[str, Any]]:
        """Start a new trial in every replica, or in those selected by ``options["replicas"]``.

        Args:
            seed: Reseeds the generator first; the same seed (and actions) gives the same trajectories. An integer
                in ``[0, MAX_RESET_SEED]`` (not a float, not a bool).
            options: Optional hand placement, each for all ``(R, N)`` agents (rows of replicas not reset are
                ignored): ``positions (R, N, 2)`` (m; inside the room, clear of walls and of each other),
                ``headings (R, N)`` (rad; default uniform), ``speeds (R, N)`` (m/s; default 0), and
                ``replicas (R,)`` bool, the replicas to reset (default all).

        Returns:
            ``obs (R, N, F)`` float32 and ``info`` (the keys of :meth:`step`, with no crash or arrival).

        Raises:
            ValueError: For a seed that is not an integer in range, an unknown option or a badly shaped or invalid
                value.
            PlacementError: If random placement fails (too many agents for the room).
        """
        self.place(seed=seed, options=options)
        shape = (self.num_replicas, self.num_agents)
        observation = self._observe(observers=self.active, sensed=self.active)
        info = self._info(
            observation,
            crashed_agent=torch.zeros(shape, dtype=torch.bool, device=self.device),
            crashed_wall=torch.zeros(shape, dtype=torch.bool, device=self.device),
            reached=torch.zeros(shape, dtype=torch.bool, device=self.device),
        )
        return observation.features, info

    def place(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None) -> None:
        """:meth:`reset` without the observation: the state of a new trial, for a caller that senses in its own kernels
        (the fused trial), so that a crowd of any size is placed in memory that grows with it, not its square."""
        if seed is not None:
            self.generator.manual_seed(check_integer("seed", seed, minimum=0, maximum=MAX_RESET_SEED))
        options = read_options(options)
        replicas = read_option(options, "replicas", (self.num_replicas,), device=self.device, dtype=torch.bool)
        if replicas is None:
            replicas = torch.ones(self.num_replicas, dtype=torch.bool, device=self.device)
        chosen = replicas.unsqueeze(-1)  # (R, 1)
        positions, headings, speeds = self.spawns.start(
            options, replicas, self.generator, max_speed=self.params.max_speed, rounds=MAX_PLACEMENT_ROUNDS
        )

        self.positions = torch.where(chosen.unsqueeze(-1), positions, self.positions)
        self.headings = torch.where(chosen, headings, self.headings)
        self.speeds = torch.where(chosen, speeds, self.speeds)
        self.velocities = velocities_from(speeds=self.speeds, headings=self.headings)
        self.active = self.active | chosen
        exits = self.spawns.assign(
            self.positions, chosen, max_speed=self.params.max_speed, queue_weight=self.params.queue_weight
        )
        self.exit_index = torch.where(chosen, exits, self.exit_index)
        self.stage = torch.where(chosen, 0, self.stage)
        self._targets = self.spawns.route_point(self.stage, self.exit_index)
        self._advance_routes()
        self.decisions = torch.where(replicas, 0, self.decisions)
        self._reset_at[replicas.cpu()] = self._steps_taken
        self._oldest_reset = int(self._reset_at.min())
        self._was_reset = True

    def step(
        self, actions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        """Advance every replica by one decision.

        Args:
            actions: Actions ``(R, N)`` int64 in ``[0, 81)``, or in the ``goal`` action frame continuous commands
                ``(R, N, 2)`` float32 (:func:`pedrl.sim.actions.apply_commands`: the speed ratio and the heading
                offset from the goal bearing); ignored for inactive agents.

        Returns:
            ``obs (R, N, F)`` float32, ``reward (R, N)`` float32, ``terminated (R, N)`` bool (left the room
            through an exit this decision), ``truncated (R, N)`` bool (still in the room when the clock reached
            ``max_decisions``), and ``info`` with ``crashed_agent``, ``crashed_wall``, ``reached`` bool
            ``(R, N)`` (left through its own exit: the goal; one that leaves through another group's exit, as a
            corridor walker stepping back out of the end it started at, gets no goal reward and is not counted),
            ``num_sensed`` int64 ``(R, N)``, ``neighbour_mask`` bool ``(R, N, k)``, ``neighbour_velocity`` float32
            ``(R, N, k, 2)`` (beside the state: :mod:`pedrl.sim.sensing`), ``speed`` float32 ``(R, N)``
            (m/s after the step) and ``decision`` (int, the trial clock). Agents inactive before the step get obs 0
            and reward 0; an agent truncated by this step still gets its final observation (it is still in the
            room), one that left gets 0.

        Raises:
            RuntimeError: If :meth:`reset` was never called.
            ValueError: If ``actions`` is neither an integer tensor of shape ``(R, N)`` nor, in the ``goal`` frame, a
                finite float tensor of shape ``(R, N, 2)``.
        """
        if not self._was_reset:
            raise RuntimeError("RoomEnv.step() called before reset()")
        shape = (self.num_replicas, self.num_agents)
        actions = check_actions(actions, shape, device=self.device, frame=self.params.action_frame)
        acting = self.active
        targets = self.targets()  # this decision's targets, for the order of action and the progress

        # ---- decide: new speeds and headings
        speeds, headings = self.decide(actions, targets)
        commanded = velocities_from(speeds=speeds, headings=headings)
        table, params = self.params.rewards, self.params
        deviation = None
        if table.deviation:
            deviation = unpriced_in_company(
                commanded_deviation(speeds, headings, self.positions, targets, params.max_speed, params.deviation_turn),
                self.positions,
                acting,
                params.deviation_radius,
                oncoming=(commanded, targets) if params.deviation_gate == "oncoming" else None,
            )
        passing = None
        if table.passing:
            passing = wrong_side_passing(
                self.positions, commanded, targets, acting, params.passing_radius, params.passing_band,
                params.passing_side,
            )  # fmt: skip
        movement, speeds, velocities = self._move(acting, speeds, headings, commanded, targets)
        progress = self._goal_distance(self.positions, targets) - self._goal_distance(movement.positions, targets)

        # ---- end of trial: door, then the clock
        self._steps_taken += 1
        self.decisions = self.decisions + 1
        in_room = acting & ~movement.reached
        truncated = in_room & (self.decisions >= self.params.max_decisions).unsqueeze(-1)
        self.positions = movement.positions
        self.speeds = speeds
        self.headings = headings
        self.velocities = velocities
        self.active = in_room & ~truncated
        self._advance_routes()

        # ---- rewards and observations: the goal only through the agent's own exit
        reached = self.spawns.own_exit(movement.reached, movement.positions, self.exit_index)
        reward = compute_rewards(
            table=table,
            reached=reached,
            crashed_wall=movement.crashed_wall,
            crashed_agent=movement.crashed_agent,
            acting=acting,
            progress=progress,
            deviation=deviation,
            passing=passing,
        )
        observation = self._observe(observers=in_room, sensed=in_room)
        info = self._info(
            observation,
            crashed_agent=movement.crashed_agent,
            crashed_wall=movement.crashed_wall,
            reached=reached,
        )
        return observation.features, reward, movement.reached, truncated, info

    def decide(self, actions: torch.Tensor, targets: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The speeds and headings ``(R, N)`` that ``actions (R, N)`` command (:func:`pedrl.sim.actions.apply_actions`
        in the room's action frame, or the continuous commands ``(R, N, 2)``,
        :func:`pedrl.sim.actions.apply_commands`, towards ``targets`` (None: :meth:`targets`)), before the motion
        model moves the bodies: what :meth:`step` applies, and what the free-walking probe
        (:mod:`pedrl.trial.walking`) measures."""
        targets = self.targets() if targets is None else targets
        bearings = None
        if self.params.action_frame == "goal":
            to_goal = targets - self.positions
            bearings = torch.atan2(to_goal[..., Y], to_goal[..., X])
        if actions.is_floating_point():
            return apply_commands(speeds=self.speeds, headings=self.headings, commands=actions,
                                  max_speed=self.params.max_speed, active=self.active, bearings=bearings)  # fmt: skip
        return apply_actions(
            speeds=self.speeds,
            headings=self.headings,
            actions=actions,
            speed_changes=self.speed_changes,
            turn_changes=self.turn_changes,
            max_speed=self.params.max_speed,
            active=self.active,
            bearings=bearings,
        )

    # ------------------------------------------------------------------ internals

    def _move(
        self,
        acting: torch.Tensor,
        speeds: torch.Tensor,
        headings: torch.Tensor,
        velocities: torch.Tensor,
        targets: torch.Tensor,
    ) -> tuple[Movement, torch.Tensor, torch.Tensor]:
        """Move the ``acting`` agents at the new ``speeds`` and ``headings`` (their ``velocities``), sub-stepped, by
        the motion model: the movement, and the speeds and velocities after it."""
        bodies = dict(positions=self.positions, velocities=velocities, active=acting)
        model, constants = self.motion, self.motion_constants
        if model.rule == "sequential":
            priority = torch.rand(self.active.shape, generator=self.generator, device=self.device)
            if model.order == "door_first":  # metres dominate, the uniform draw breaks ties
                priority = self._goal_distance(self.positions, targets) + priority * 1e-3
        if model.contact != "stop":
            movement = move_agents_sliding(**bodies, motion=constants, priority=priority)
            # the speed is the distance actually walked; the heading stays the commanded one
            walked = torch.linalg.vector_norm(movement.positions - self.positions, dim=-1) / self.params.decision_length
            speeds = torch.where(acting, walked.clamp_max(self.params.max_speed), speeds)
            velocities = velocities_from(speeds=speeds, headings=headings)
        else:
            if model.rule == "sequential":
                # off the CPU: fixed rounds with masks, so that a decision never waits for the host (same result)
                movement = move_agents_sequential(
                    **bodies, motion=constants, priority=priority, sync_free=self.device.type != "cpu"
                )
            else:
                movement = move_agents(**bodies, motion=constants)
            speeds = torch.where(movement.blocked, 0.0, speeds)
            velocities = torch.where(movement.blocked.unsqueeze(-1), 0.0, velocities)
        return movement, speeds, velocities

    def _observe(self, *, observers: torch.Tensor, sensed: torch.Tensor) -> Observation:
        if not self._torch_memory_checked:  # the torch step senses every pair: refuse what cannot fit, once
            check_memory(
                {"the torch step's pairs (sensing, collisions)": self.step_memory(kernels=False)},
                device=self.device,
                advice="fewer agents or replicas; on the CPU, pedrl-eval's fused trial (fused=null) senses through"
                " grids of cells in memory linear in the agents",
            )
            self._torch_memory_checked = True
        sense = compiled_observe() if self.params.compile_sensing else observe
        return sense(
            positions=self.positions,
            velocities=self.velocities,
            headings=self.headings,
            speeds=self.speeds,
            observers=observers,
            sensed=sensed,
            geometry=self.geometry,
            goals=self.targets(),
            num_neighbours=self.params.num_neighbours,
            num_walls=self.params.num_walls,
        )

    @staticmethod
    def _goal_distance(positions: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """Distance from each centre ``(R, N, 2)`` to its target ``(R, N, 2)``: ``(R, N)`` (m)."""
        return torch.hypot(positions[..., X] - targets[..., X], positions[..., Y] - targets[..., Y])

    def _info(
        self,
        observation: Observation,
        *,
        crashed_agent: torch.Tensor,
        crashed_wall: torch.Tensor,
        reached: torch.Tensor,
    ) -> dict[str, Any]:
        return {
            "crashed_agent": crashed_agent,
            "crashed_wall": crashed_wall,
            "reached": reached,
            "num_sensed": observation.num_sensed,
            "neighbour_mask": observation.neighbour_mask,
            "neighbour_velocity": observation.neighbour_velocity,
            "speed": self.speeds,
            "decision": self.decision,
        }
