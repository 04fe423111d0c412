"""A room stepped decision by decision by the compiled kernels, for a controller that acts in torch between them.

The fused trial (:mod:`pedrl.trial.fused`) runs a whole trial in one compiled call, with the learned tables inside it.
A controller that cannot live in a compiled kernel (a neural network) needs the decision loop in Python: a
:class:`CompiledRoom` wraps a :class:`pedrl.sim.RoomEnv` and gives it the same ``reset`` / ``step`` contract, but every
decision's physics and sensing run in :func:`step_rooms` (the fused trial's stage kernels,
:func:`pedrl.sim.step_kernel.act_room` and :func:`pedrl.sim.sensing_kernel.sense_room`, over the rooms in parallel)
instead of the torch step. :func:`pedrl.trial.loop.crowd_loop` drives it as it drives the room itself.

The kernels match the torch step within the tolerances of :mod:`pedrl.trial.twins`, not to the bit (the order of the
movers comes from a counter-based stream per room, :mod:`pedrl.sim.streams`, seeded by one draw of the room's
generator at each reset); a seed gives the same trial at any thread count.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from numba import prange

from pedrl._numba import cached_njit
from pedrl.sim import RoomEnv
from pedrl.sim.room_checks import check_actions
from pedrl.sim.sensing_kernel import room_search, sense_room
from pedrl.sim.state import KernelState, RoomState
from pedrl.sim.step_kernel import NO_COMMANDS, Events, Work, act_room, act_scratch
from pedrl.sim.streams import next_uniform, seed_streams
from pedrl.trial.fused import room_inputs

__all__ = ["CompiledRoom", "step_rooms"]


@cached_njit(nogil=True, parallel=True)
def step_rooms(first, state, actions, commands, room, walls, exits, routes, work, events, features, num_sensed,
               velocity, streams):  # fmt: skip
    """One decision of every room in parallel (``first``: the rooms' first observation instead, after a reset):
    act (:func:`~pedrl.sim.step_kernel.act_room`: the ``actions`` ``(R, N)`` or, where it has rows, the continuous
    ``commands`` ``(R, N, 2)``, the move, the exits, the clock, the rewards into ``events``), then sense the agents
    still in each room into ``features (R, N, F)``, ``num_sensed (R, N)`` and ``velocity (R, N, k, 2)``
    (:func:`~pedrl.sim.sensing_kernel.sense_room`). ``state`` is updated in place."""
    rooms, num_agents = actions.shape
    size = max(num_agents, walls.starts.shape[0])
    for r in prange(rooms):
        distances, indices = np.empty((2, size), np.float32), np.empty((2, size), np.int64)
        present = state.active
        if not first:
            scratch = act_scratch(num_agents)
            for i in range(num_agents):
                work.draws[r, i] = next_uniform(streams, r)  # the order of the movers
            act_room(r, state, actions, commands, room, walls, exits, routes, work, events, scratch)
            present = events.in_room
        sense_room(r, state, present, walls, room.num_neighbours, room.num_walls, room_search(room), features,
                   num_sensed, distances, indices, velocity)  # fmt: skip


class CompiledRoom:
    """``env``'s rooms with :meth:`reset` and :meth:`step` run by the compiled kernels (module docstring); every other
    attribute is the room's own (``num_replicas``, ``num_agents``, ``positions``, ``active``, ...), kept current: after
    each decision the room takes a copy of the kernels' state (new tensors, as its torch step makes).

    :func:`pedrl.trial.crowd.run_crowd` builds one where :func:`pedrl.trial.crowd.choose_path` found that the fused
    path runs the room (the kernels' allow-list).
    """

    def __init__(self, env: RoomEnv) -> None:
        from pedrl.trial.fused import set_kernel_threads

        set_kernel_threads(torch.get_num_threads())
        self.env = env
        rooms, agents = env.num_replicas, env.num_agents
        self._inputs = None
        self._work = Work.allocate(rooms, agents, env.num_substeps)
        self._events = Events.allocate(rooms, agents)
        self._features = np.zeros((rooms, agents, env.num_features), np.float32)
        self._num_sensed = np.zeros((rooms, agents), np.int64)
        self._velocity = np.zeros((rooms, agents, env.params.num_neighbours, 2), np.float32)
        self._actions = np.zeros((rooms, agents), np.int64)
        self._commands = NO_COMMANDS
        self._streams = np.empty(rooms, np.uint64)
        self._state = None
        self._slots = torch.arange(env.params.num_neighbours)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def reset(self, *, seed: int | None = None) -> tuple[torch.Tensor, dict[str, Any]]:
        """A new trial in every room (the room's :meth:`~pedrl.sim.RoomEnv.place`, its generator draws the scene and
        the kernels' streams): ``(obs, info)`` as :meth:`pedrl.sim.RoomEnv.reset` gives them."""
        env = self.env
        env.place(seed=seed)
        # the walkers' routes are drawn at placement (each its own way round the walls): read them after it
        self._inputs = room_inputs(env)
        self._state = env.state.clone().arrays()  # the kernels' own copy
        draw = int(torch.randint(0, 2**62, (1,), generator=env.generator))
        seed_streams(np.uint64(draw), self._streams)
        self._run(first=True)
        self._publish(0)
        events = self._events
        for flags in (events.crashed_agent, events.crashed_wall, events.goal, events.left):
            flags[:] = False
        obs, info = self._observation()
        return obs, info

    def step(
        self, actions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        """One decision of every room: ``(obs, reward, terminated, truncated, info)`` as
        :meth:`pedrl.sim.RoomEnv.step` gives them (copies: the next decision does not change them), for ``actions``
        as that step takes them (action indices or continuous commands, checked as it checks them)."""
        if self._state is None:
            raise RuntimeError("CompiledRoom.step() called before reset()")
        env = self.env
        actions = check_actions(actions, (env.num_replicas, env.num_agents), device=torch.device("cpu"),
                                frame=env.params.action_frame)  # fmt: skip
        if actions.is_floating_point():
            self._commands = actions.numpy()
        else:
            self._commands = NO_COMMANDS
            self._actions[:] = actions.numpy()
        self._run(first=False)
        self._publish(1)
        events = self._events
        obs, info = self._observation()
        terminated = torch.from_numpy(events.left.copy())
        truncated = torch.from_numpy(events.in_room & ~self._state.active)
        return obs, torch.from_numpy(events.reward.copy()), terminated, truncated, info

    def _publish(self, decisions: int) -> None:
        """The kernels' state, copied, as the room's (a caller may hold the room's tensors of a decision before: the
        kernels change their own arrays in place, never the room's)."""
        copied = KernelState(*(array.copy() for array in self._state))
        self.env.load_state(RoomState.from_arrays(copied), decisions_taken=decisions)

    def _run(self, *, first: bool) -> None:
        inputs = self._inputs
        step_rooms(first, self._state, self._actions, self._commands, inputs.room, inputs.walls, inputs.exits,
                   inputs.routes, self._work, self._events, self._features, self._num_sensed, self._velocity,
                   self._streams)  # fmt: skip

    def _observation(self) -> tuple[torch.Tensor, Mapping[str, Any]]:
        events = self._events
        num_sensed = torch.from_numpy(self._num_sensed.copy())
        info = {
            "crashed_agent": torch.from_numpy(events.crashed_agent.copy()),
            "crashed_wall": torch.from_numpy(events.crashed_wall.copy()),
            "reached": torch.from_numpy(events.goal.copy()),
            "num_sensed": num_sensed,
            "neighbour_mask": self._slots < num_sensed.unsqueeze(-1),
            "neighbour_velocity": torch.from_numpy(self._velocity.copy()),
            "speed": torch.from_numpy(self._state.speeds.copy()),
            "decision": self.env.decision,
        }
        return torch.from_numpy(self._features.copy()), info
