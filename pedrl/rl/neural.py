"""A learned Q-network you can carry: what ``algo=dqn`` learns and what evaluation and validation run.

:class:`NeuralPolicy` is the neural twin of :class:`pedrl.rl.TabularPolicy`: the same ``act(obs, info, epsilon=,
generator=)``, ``controller()``, ``save`` and ``metadata``; its state is the network of :mod:`pedrl.rl.network` and
the standardisation of its inputs. Replica ``i`` of a room acts with process ``(i // E) mod P``'s network (the
tables' rule, :class:`pedrl.rl.policy.TableLayout`, with one table per process).

:class:`ContinuousPolicy` is its twin with a continuous head (PPO's ``algo.actions=continuous``): the network gives
two numbers per agent, squashed (:func:`squash`) into the command the room executes as it is (the speed ratio and the
heading offset from the goal bearing, :data:`pedrl.sim.actions.COMMAND_WIDTH`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Final

import torch

from pedrl.common.checks import check_number
from pedrl.rl.network import QNetwork, head_of, head_outputs, layer_widths
from pedrl.rl.policy import (
    PolicyController,
    TableLayout,
    check_observations,
    read_policy_file,
    register_learner,
    write_policy_file,
)
from pedrl.rl.qtable import NUM_ACTIONS
from pedrl.sim.actions import COMMAND_WIDTH
from pedrl.vq.encoder import EncoderSettings, StateEncoder

NETWORK_PREFIX: Final = "network"
INPUT_KEYS: Final = ("inputs/mean", "inputs/std")
"""The standardisation of the prepared features: ``(F,)`` float32 each."""
NEURAL_LEARNER: Final = "neural"
"""``learner`` of a neural policy file's metadata."""
CONTINUOUS_LEARNER: Final = "continuous"
"""``learner`` of a continuous policy file's metadata (:class:`ContinuousPolicy`)."""
MAX_OFFSET: Final = math.pi / 2
"""Widest heading offset of a continuous command (rad): 90 degrees either side of the goal bearing, as the ``goal``
frame's widest turns."""
COMPANY_HEADINGS: Final = ("none", "added", "routed")
"""Values of ``algo.company_heading``: no company term; a company term added where another walker is sensed
(:func:`command_means`); that term with the decisions in company teaching it alone (``routed``)."""
COMPANY_WIDTH: Final = COMMAND_WIDTH + 1
"""Outputs of a continuous network with a company heading (``algo.company_heading``): the speed, the heading alone
and the heading's term added where another walker is sensed (:func:`command_means`)."""
SPEED_OVERSHOOT: Final = 0.05
"""The squashed speed ratio spans ``[-0.05, 1.05]`` and the room clips it to ``[0, 1]``: a finite network output
reaches the top speed, and standing, exactly."""


class NeuralPolicy:
    """Acts epsilon-greedily on ``network``'s Q-values of the agents' prepared, standardised observations (a
    :class:`pedrl.rl.policy.LearnedPolicy` of learner :data:`NEURAL_LEARNER`).

    Args:
        encoder: prepares observations (:meth:`pedrl.vq.StateEncoder.prepare`; it holds no quantizer).
        network: ``P`` Q-networks (:class:`pedrl.rl.network.QNetwork`).
        mean, std: ``(F,)`` the standardisation of the prepared features.
        rooms_per_process: E of the replica-to-process rule; 1 for a loaded policy.
        metadata: plain values carried with the policy (the algorithm, the training config).
        neighbour_velocity: the network also reads each neighbour slot's velocity in the goal frame (the room's
            ``info["neighbour_velocity"]``, m/s, 0 in empty slots; ``algo.neighbour_velocity``).
    """

    learner: ClassVar[str] = NEURAL_LEARNER

    def __init__(
        self,
        encoder: StateEncoder,
        network: QNetwork,
        mean: torch.Tensor,
        std: torch.Tensor,
        *,
        rooms_per_process: int = 1,
        metadata: Mapping[str, Any] | None = None,
        neighbour_velocity: bool = False,
    ) -> None:
        self.encoder, self.network = encoder, network
        self.neighbour_velocity = neighbour_velocity
        self.mean, self.std = mean, std
        self.metadata = dict(metadata or {})
        self.layout = TableLayout(network.processes, 1, 1, rooms_per_process)
        self._generator: torch.Generator | None = None
        self._slots = torch.arange(encoder.settings.num_neighbours, device=mean.device)

    @property
    def num_processes(self) -> int:
        return self.network.processes

    num_tables = 1
    """One network per process, shared by its agents (what evaluation reports as the tables per process)."""

    @property
    def num_actions(self) -> int:
        return self.network.actions

    @property
    def num_inputs(self) -> int:
        """Width of a network input: the prepared features, one presence flag per neighbour slot and, with
        ``neighbour_velocity``, two velocity components per slot."""
        return self.network.widths[0]

    @property
    def device(self) -> torch.device:
        return self.mean.device

    # ------------------------------------------------------------------ inputs and values
    def inputs(
        self, obs: torch.Tensor, num_sensed: torch.Tensor, decision: int, velocity: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Network inputs ``(B, D)`` of observations ``(B, F)`` with ``num_sensed (B,)`` neighbours (module
        docstring of :mod:`pedrl.rl.network`) and, for a policy that reads them, their velocities ``(B, k, 2)``."""
        prepared = self.encoder.prepare(obs, num_sensed, decision, None)
        present = (self._slots < num_sensed.unsqueeze(-1)).to(prepared.dtype)
        parts = [(prepared - self.mean) / self.std, present]
        if self.neighbour_velocity:
            if velocity is None:
                raise ValueError("this policy reads the neighbours' velocities: pass info['neighbour_velocity']")
            parts.append(velocity.reshape(velocity.shape[0], -1).to(prepared.dtype))
        return torch.cat(parts, dim=-1)

    def info_inputs(self, obs: torch.Tensor, info: Mapping[str, Any], rows: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`inputs` of the flattened ``obs (R, N, F)`` and ``info`` as a room returns them, of the agents
        ``rows`` of the flat batch (all when None)."""
        flat, num_sensed = obs.reshape(-1, obs.shape[-1]), info["num_sensed"].reshape(-1)
        velocity = None
        if self.neighbour_velocity:
            if "neighbour_velocity" not in info:
                raise ValueError("info holds no 'neighbour_velocity': this policy reads the neighbours' velocities")
            velocity = info["neighbour_velocity"].reshape(flat.shape[0], -1, 2)
        if rows is not None:
            flat, num_sensed = flat.index_select(0, rows), num_sensed.index_select(0, rows)
            velocity = None if velocity is None else velocity.index_select(0, rows)
        return self.inputs(flat, num_sensed, info["decision"], velocity)

    def inputs_of(self, obs: torch.Tensor, info: Mapping[str, Any], mask: torch.Tensor) -> torch.Tensor:
        """Network inputs ``(R N, D)`` of the agents in ``mask (R N,)`` (:meth:`info_inputs`); zeros for the others:
        what a learner's driver keeps of a decision."""
        inputs = torch.zeros(mask.shape[0], self.num_inputs, device=obs.device)
        rows = torch.nonzero(mask).squeeze(1)
        if rows.shape[0]:
            inputs.index_copy_(0, rows, self.info_inputs(obs, info, rows))
        return inputs

    def values(self, inputs: torch.Tensor, process: torch.Tensor, *, network: QNetwork | None = None) -> torch.Tensor:
        """Q-values ``(B, U)`` of ``inputs (B, D)``, row ``b`` through process ``process[b]``'s network (of
        ``network``, default this policy's)."""
        network = self.network if network is None else network
        processes = network.processes
        if processes == 1:
            return network(inputs.unsqueeze(0)).squeeze(0)
        counts = torch.bincount(process, minlength=processes)
        order = torch.argsort(process, stable=True)
        owner = process.index_select(0, order)
        start = torch.cumsum(counts, 0) - counts
        slot = torch.arange(order.shape[0], device=inputs.device) - start.index_select(0, owner)
        padded = inputs.new_zeros(processes, int(counts.max()), inputs.shape[1])
        padded[owner, slot] = inputs.index_select(0, order)
        values = network(padded)[owner, slot]
        return torch.empty_like(values).index_copy_(0, order, values)

    def choose(self, values: torch.Tensor, epsilon: float, generator: torch.Generator) -> torch.Tensor:
        """Epsilon-greedy actions ``(B,)`` on Q-values ``(B, U)``: the best action, or with probability
        ``epsilon`` a uniform one (drawn from ``generator``)."""
        actions = values.argmax(dim=1)
        if epsilon > 0:
            batch = values.shape[0]
            explore = torch.rand(batch, generator=generator, device=values.device) < epsilon
            random = torch.randint(values.shape[1], (batch,), generator=generator, device=values.device)
            actions = torch.where(explore, random, actions)
        return actions

    def act(
        self,
        obs: torch.Tensor,
        info: Mapping[str, Any],
        *,
        epsilon: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """Actions ``(R, N)`` int64 (a :class:`ContinuousPolicy`'s commands ``(R, N, 2)``) for observations ``obs (R,
        N, F)`` and ``info`` (as ``RoomEnv`` returns them), as :meth:`pedrl.rl.TabularPolicy.act`: ``epsilon`` the
        share of random actions, drawn from ``generator``."""
        check_number("epsilon", epsilon, low=0.0, high=1.0)
        check_observations(obs, info, self.encoder.settings, self.device)  # the tables' contract
        if generator is None:
            if self._generator is None:
                self._generator = torch.Generator(device=self.device)
                self._generator.seed()
            generator = self._generator
        replicas, agents = obs.shape[0], obs.shape[1]
        process, _ = self.layout.of(replicas, agents, obs.device)
        flat = self.info_inputs(obs, info)
        with torch.no_grad():
            values = self.values(flat, process)
        chosen = self.choose(values, epsilon, generator)
        return chosen.view(replicas, agents, *chosen.shape[1:])

    def controller(self, epsilon: float = 0.0, generator: torch.Generator | None = None) -> NeuralController:
        """This policy as a controller of the evaluation engine, with a fixed ``epsilon`` and ``generator``."""
        return NeuralController(self, epsilon=epsilon, generator=generator)

    # ------------------------------------------------------------------ checks and files
    def check(self, num_actions: int | None = None) -> None:
        """One-line ``ValueError`` unless the network reads the encoder's features and presence flags, gives
        ``num_actions`` values (when given), and the standardisation is finite with a positive spread."""
        settings = self.encoder.settings
        width = input_width(settings, neighbour_velocity=self.neighbour_velocity)
        if self.num_inputs != width:
            velocities = f" and {2 * settings.num_neighbours} velocity components" if self.neighbour_velocity else ""
            raise ValueError(
                f"the network reads {self.num_inputs} inputs: must read {width} ({settings.num_features} features, "
                f"{settings.num_neighbours} presence flags{velocities})"
            )
        self.check_outputs(num_actions)
        for name, tensor in zip(INPUT_KEYS, (self.mean, self.std), strict=True):
            if tensor.dtype != torch.float32 or tuple(tensor.shape) != (settings.num_features,):
                raise ValueError(
                    f"tensor {name} is {tensor.dtype} {tuple(tensor.shape)}: must be float32 ({settings.num_features},)"
                )
            if not bool(torch.isfinite(tensor).all()):
                raise ValueError(f"tensor {name} holds NaN or infinite values: must be finite")
        if not bool((self.std > 0).all()):
            raise ValueError("tensor inputs/std holds values <= 0: must be > 0")

    def check_outputs(self, num_actions: int | None) -> None:
        """One-line ``ValueError`` unless the network gives ``num_actions`` values (when given)."""
        if num_actions is not None and self.num_actions != num_actions:
            raise ValueError(f"the network gives {self.num_actions} values: must give {num_actions}, one per action")

    def tensors(self) -> dict[str, torch.Tensor]:
        """The network and the standardisation as named tensors (as files hold them)."""
        return {**self.network.tensors(NETWORK_PREFIX), INPUT_KEYS[0]: self.mean, INPUT_KEYS[1]: self.std}

    def save(self, path: str | Path) -> Path:
        """Write the network and its standardisation, with their metadata, to ``path``
        (:func:`pedrl.rl.policy.write_policy_file`)."""
        return write_policy_file(self, path)

    def kernel_reason(self, env: Any) -> str | None:
        """None: the network acts in torch between the compiled steps of any room the kernels run
        (:class:`pedrl.trial.stepped.CompiledRoom`; the room's own reasons aside)."""
        return None

    def kernel_arrays(self) -> None:
        """None: the fused trial reads no network; its controller is ``stepped``
        (:meth:`kernel_reason`)."""
        return None

    @classmethod
    def load(cls, path: str | Path, *, device: str | torch.device = "cpu") -> NeuralPolicy:
        """Read a neural policy file written by :meth:`save` (:func:`pedrl.rl.policy.read_policy_file`).

        Raises:
            CheckpointError: one line naming the file and what is wrong.
        """
        return read_policy_file(path, device=device, learner=cls.learner)


def neural_from_tensors(
    settings: EncoderSettings,
    tensors: Mapping[str, torch.Tensor],
    *,
    num_actions: int | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> NeuralPolicy:
    """A checked policy from a file's tensors (``network/...`` and ``inputs/...``) and its encoder settings; tensors
    of other names are ignored (a training checkpoint's optimizer, replay memory and target network)."""
    return _from_tensors(NeuralPolicy, settings, tensors, num_actions=num_actions, metadata=metadata)


def continuous_from_tensors(
    settings: EncoderSettings,
    tensors: Mapping[str, torch.Tensor],
    *,
    num_actions: int | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> ContinuousPolicy:
    """:func:`neural_from_tensors` of a :class:`ContinuousPolicy` (``num_actions``, the room's discrete actions, is
    not read: its network gives a command)."""
    return _from_tensors(ContinuousPolicy, settings, tensors, num_actions=None, metadata=metadata)


def _from_tensors(cls: type, settings: EncoderSettings, tensors: Mapping[str, torch.Tensor], *,
                  num_actions: int | None, metadata: Mapping[str, Any] | None) -> Any:  # fmt: skip
    """A checked ``cls`` (:class:`NeuralPolicy` or :class:`ContinuousPolicy`) of a file's tensors."""
    processes, widths = layer_widths(tensors, NETWORK_PREFIX)
    device = tensors[f"{NETWORK_PREFIX}/w0"].device
    branching = head_outputs("branching", NUM_ACTIONS)
    actions = num_actions if num_actions is not None else (NUM_ACTIONS if widths[-1] == branching else widths[-1])
    network = QNetwork(processes, widths[0], widths[1:-1], actions, head=head_of(widths[-1], actions), device=device)
    network.load_tensors(tensors, NETWORK_PREFIX)
    network.requires_grad_(False)
    for name in INPUT_KEYS:
        if name not in tensors:
            raise ValueError(f"tensor {name} is missing")
    velocity = widths[0] == input_width(settings, neighbour_velocity=True)  # the width tells
    policy = cls(StateEncoder(settings), network, *(tensors[name] for name in INPUT_KEYS), metadata=metadata,
                 neighbour_velocity=velocity)  # fmt: skip
    policy.check(num_actions)
    return policy


def company_column(settings: EncoderSettings) -> int:
    """The input column of the nearest neighbour slot's presence flag (the first flag after the ``F`` features): 1
    where the walker senses another, the ``c`` of :func:`command_means`."""
    return settings.num_features


def input_width(settings: EncoderSettings, *, neighbour_velocity: bool = False) -> int:
    """Width of a network input over ``settings``' features: ``F + k`` (presence flags), ``+ 2k`` with the
    neighbours' velocities."""
    return settings.num_features + settings.num_neighbours * (3 if neighbour_velocity else 1)


class NeuralController(PolicyController):
    """A :class:`NeuralPolicy` with a fixed ``epsilon`` and ``generator``: the evaluation engine's controller
    (``act(env, obs, info)``). It acts in torch between decisions that the compiled kernels step
    (:class:`pedrl.trial.stepped.CompiledRoom`) wherever they can run the room."""

    stepped = True
    """Run by :func:`pedrl.trial.crowd.run_crowd` in a :class:`~pedrl.trial.stepped.CompiledRoom` where it can."""


class ContinuousPolicy(NeuralPolicy):
    """A :class:`NeuralPolicy` whose network gives a command per agent, not Q-values (a
    :class:`pedrl.rl.policy.LearnedPolicy` of learner :data:`CONTINUOUS_LEARNER`): it acts with the squashed output
    (:func:`squash`, the mean of PPO's squashed Gaussian), and with probability ``epsilon`` a uniform command instead
    (a speed ratio in ``[0, 1]``, an offset within :data:`MAX_OFFSET`). Its ``act`` gives commands ``(R, N, 2)``
    float32, which :meth:`pedrl.sim.RoomEnv.step` executes in the ``goal`` action frame. A network of
    :data:`COMPANY_WIDTH` outputs has a company heading (:func:`command_means`)."""

    learner: ClassVar[str] = CONTINUOUS_LEARNER

    def values(self, inputs: torch.Tensor, process: torch.Tensor, *, network: QNetwork | None = None) -> torch.Tensor:
        """The Gaussian's means ``(B, 2)`` of ``inputs (B, D)`` (:func:`command_means`); another ``network``'s
        outputs (the critic's values) as they are."""
        outputs = super().values(inputs, process, network=network)
        if network is not None and network is not self.network:
            return outputs
        return command_means(outputs, inputs, company_column(self.encoder.settings))

    def choose(self, values: torch.Tensor, epsilon: float, generator: torch.Generator) -> torch.Tensor:
        """Commands ``(B, 2)`` of the network's outputs ``(B, 2)`` (:func:`squash`), a uniform one with probability
        ``epsilon`` (drawn from ``generator``)."""
        commands = squash(values)
        if epsilon > 0:
            batch = values.shape[0]
            explore = torch.rand(batch, generator=generator, device=values.device) < epsilon
            uniform = torch.rand(batch, COMMAND_WIDTH, generator=generator, device=values.device)
            uniform = torch.stack((uniform[:, 0], MAX_OFFSET * (2 * uniform[:, 1] - 1)), dim=1)
            commands = torch.where(explore.unsqueeze(1), uniform, commands)
        return commands

    def check_outputs(self, num_actions: int | None) -> None:
        """One-line ``ValueError`` unless the network gives a command (``num_actions`` is the room's discrete count,
        not read)."""
        if self.num_actions not in (COMMAND_WIDTH, COMPANY_WIDTH) or self.network.head != "joint":
            raise ValueError(
                f"the network gives {self.num_actions} values: a continuous policy's gives {COMMAND_WIDTH} (or "
                f"{COMPANY_WIDTH} with a company heading)"
            )


def command_means(
    outputs: torch.Tensor, inputs: torch.Tensor, company_column: int, *, routed: bool = False
) -> torch.Tensor:
    """The Gaussian's means ``(..., 2)`` of a continuous network's ``outputs`` for its ``inputs (..., D)``: the outputs
    themselves where they are two; of :data:`COMPANY_WIDTH` outputs ``(u_speed, u_alone, u_company)``, the speed and
    the heading ``u_alone + c u_company``, ``c`` the input ``company_column`` (the nearest neighbour slot's presence
    flag: 1 where the walker senses another, 0 alone). The heading alone is then one output of the network, which the
    heading prior pulls towards the goal bearing (:mod:`pedrl.rl.ppo`), and what the walker learns of others goes into
    the company term, which only acts where someone is sensed: the decomposition that lets a walker head straight
    alone and deviate in company. ``routed`` (learning only; the values are the same): where ``c`` is 1 the heading
    alone is held constant (``detach``), so that a decision in company teaches the company term and not the heading
    alone, which learns from lone decisions and the prior only."""
    if outputs.shape[-1] == COMMAND_WIDTH:
        return outputs
    company, alone = inputs[..., company_column], outputs[..., 1]
    if routed:
        alone = torch.where(company > 0, alone.detach(), alone)
    return torch.stack((outputs[..., 0], alone + company * outputs[..., 2]), dim=-1)


def squash(outputs: torch.Tensor) -> torch.Tensor:
    """Commands ``(..., 2)`` of unbounded outputs ``(..., 2)``: ``0.5 + 0.55 tanh(u0)`` (the speed ratio, clipped
    to ``[0, 1]`` by the room: :data:`SPEED_OVERSHOOT`) and ``MAX_OFFSET tanh(u1)`` (the heading offset, rad)."""
    bounded = torch.tanh(outputs)
    return torch.stack((0.5 + (0.5 + SPEED_OVERSHOOT) * bounded[..., 0], MAX_OFFSET * bounded[..., 1]), dim=-1)


register_learner(NEURAL_LEARNER, neural_from_tensors)
register_learner(CONTINUOUS_LEARNER, continuous_from_tensors)
