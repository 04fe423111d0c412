"""The Q-network of the neural learner: one multilayer perceptron per learning process, its inputs, and its checks.

Every agent of a process acts with its process's network (independent learners with shared parameters). The ``P``
networks are one module with weights ``(P, in, out)``, so that every process's forward pass and update is one batched
matrix product (``torch.baddbmm``): the processes stay independent (no weight is shared between them, and Adam's
moments are per element), exactly as ``P`` separate networks.

The input of agent ``i`` is its deictic state (the 28 features of the paper's room, ``3 + 3k + 2w``) as the tables'
quantizers see it (:meth:`pedrl.vq.StateEncoder.prepare`: distances as ``log(1 + d)``, empty neighbour slots 0),
standardised by the mean and spread of states recorded on a random walk, followed by ``k`` flags that say which
neighbour slots hold a neighbour (``slot < num_sensed``): without them an empty slot would read as a neighbour at
distance 0. The slots come sorted by distance, nearest first, a canonical order, so a plain perceptron sees the same
neighbour in the same slot; a permutation-invariant encoder (Deep Sets) would buy nothing the order does not give,
at a higher cost per decision.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final

import torch

from pedrl.common.checks import check_choice, check_integer
from pedrl.sim.actions import NUM_SPEED_CHANGES, NUM_TURNS

MAX_WIDTH: Final = 1 << 16
"""Widest hidden layer (units): wider is a typo (a 65,536-wide square layer holds 4 Gi weights)."""
MAX_LAYERS: Final = 16
"""Most hidden layers."""
HEADS: Final = ("joint", "branching")
"""What the last layer gives (``algo.head``). ``joint``: one value per action (81). ``branching``: a state value
``V``, one advantage per speed index ``A_s`` and one per turn index ``A_t`` (1 + 9 + 9 = 19 outputs), the Q-value of
action ``(i, j)`` being ``V + A_s[i] - mean(A_s) + A_t[j] - mean(A_t)``: action branching (Tavakoli, Pardo and
Kormushev 2018) with a dueling state value (Wang et al. 2016), so that every decision teaches the value of its speed
and of its turn (each seen in 1 of 9 decisions, not 1 of 81) and the values of two actions that differ in one
component differ by that component's advantage alone."""


def check_hidden(hidden: object) -> tuple[int, ...]:
    """``hidden`` as a tuple of layer widths; one line unless it is a non-empty list of integers in
    ``[1, MAX_WIDTH]``."""
    if isinstance(hidden, str | bytes) or not isinstance(hidden, Sequence) or not 1 <= len(hidden) <= MAX_LAYERS:
        raise ValueError(
            f"hidden={hidden!r} is invalid: must be a list of 1 to {MAX_LAYERS} layer widths, e.g. [256, 256]"
        )
    for width in hidden:
        if isinstance(width, bool) or not isinstance(width, int) or not 1 <= width <= MAX_WIDTH:
            raise ValueError(
                f"hidden={list(hidden)!r} is invalid: each layer width must be an integer in [1, {MAX_WIDTH}]"
            )
    return tuple(hidden)


def head_outputs(head: str, actions: int) -> int:
    """Width of the last layer of a ``head`` (:data:`HEADS`) over ``actions`` actions (one line for a head that
    cannot give them: ``branching`` needs the room's 9 x 9)."""
    check_choice("head", head, HEADS)
    if head == "joint":
        return actions
    if actions != NUM_SPEED_CHANGES * NUM_TURNS:
        raise ValueError(
            f"head='branching' is invalid for {actions} actions: it needs {NUM_SPEED_CHANGES} x {NUM_TURNS} = 81"
        )
    return 1 + NUM_SPEED_CHANGES + NUM_TURNS


def head_of(outputs: int, actions: int) -> str:
    """The head whose last layer is ``outputs`` wide over ``actions`` actions (a stored network's), or one line."""
    for head in HEADS:
        if head != "joint" and actions != NUM_SPEED_CHANGES * NUM_TURNS:
            continue
        if head_outputs(head, actions) == outputs:
            return head
    raise ValueError(f"the network's last layer gives {outputs} values: must give {actions} (joint) or 19 (branching)")


def head_values(head: str, outputs: torch.Tensor) -> torch.Tensor:
    """Q-values ``(..., U)`` of the last layer's ``outputs (..., O)`` through ``head`` (:data:`HEADS`): the network's
    and its ONNX graph's (:mod:`pedrl.onnx_export`)."""
    if head == "joint":
        return outputs
    value, speed, turn = torch.split(outputs, (1, NUM_SPEED_CHANGES, NUM_TURNS), dim=-1)
    speed = speed - speed.mean(-1, keepdim=True)
    turn = turn - turn.mean(-1, keepdim=True)
    return (value.unsqueeze(-1) + speed.unsqueeze(-1) + turn.unsqueeze(-2)).flatten(-2)


class QNetwork(torch.nn.Module):
    """``P`` perceptrons ``inputs -> hidden... -> outputs`` (ReLU between layers), evaluated together, giving
    ``actions`` Q-values through their ``head`` (:data:`HEADS`).

    Args:
        processes: P, independent networks.
        inputs: width of an input.
        hidden: widths of the hidden layers.
        actions: U, the Q-values an input gets.
        head: ``joint`` (the last layer gives the U values) or ``branching`` (a state value and an advantage per
            speed and per turn index).
        generator: draws the initial weights (PyTorch's ``nn.Linear`` rule: uniform in ``+-1/sqrt(fan_in)``).
    """

    def __init__(
        self,
        processes: int,
        inputs: int,
        hidden: Sequence[int],
        actions: int,
        *,
        head: str = "joint",
        generator: torch.Generator | None = None,
        device: str | torch.device = "cpu",
    ) -> None:
        super().__init__()
        check_integer("processes", processes, minimum=1)
        check_integer("inputs", inputs, minimum=1)
        check_integer("actions", actions, minimum=1)
        self.actions, self.head = actions, head
        self.widths = (inputs, *check_hidden(hidden), head_outputs(head, actions))
        self.weights = torch.nn.ParameterList()
        self.biases = torch.nn.ParameterList()
        for fan_in, fan_out in zip(self.widths[:-1], self.widths[1:], strict=True):
            bound = 1.0 / math.sqrt(fan_in)
            weight = torch.rand(processes, fan_in, fan_out, generator=generator, device=device) * 2 - 1
            bias = torch.rand(processes, 1, fan_out, generator=generator, device=device) * 2 - 1
            self.weights.append(torch.nn.Parameter(weight * bound))
            self.biases.append(torch.nn.Parameter(bias * bound))

    @property
    def processes(self) -> int:
        return self.weights[0].shape[0]

    @property
    def num_parameters(self) -> int:
        """Weights and biases of one process's network."""
        return sum(p[0].numel() for p in self.parameters())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Q-values ``(P, B, U)`` of inputs ``(P, B, inputs)`` (row ``p`` through network ``p``)."""
        last = len(self.weights) - 1
        for layer, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = torch.baddbmm(bias, x, weight)
            if layer < last:
                x = torch.relu(x)
        return head_values(self.head, x)

    def twin(self, *, device: str | torch.device | None = None) -> QNetwork:
        """A network of the same shape and head (its own weights, drawn afresh): the target network's frame."""
        return QNetwork(self.processes, self.widths[0], self.widths[1:-1], self.actions, head=self.head,
                        device=device if device is not None else self.weights[0].device)  # fmt: skip

    def tensors(self, prefix: str) -> dict[str, torch.Tensor]:
        """The weights as named tensors, ``<prefix>/w<l>`` and ``<prefix>/b<l>`` for layer ``l``."""
        named = {}
        for layer, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            named[f"{prefix}/w{layer}"] = weight.detach()
            named[f"{prefix}/b{layer}"] = bias.detach()
        return named

    def load_tensors(self, tensors: Mapping[str, torch.Tensor], prefix: str) -> None:
        """Copy the weights of :meth:`tensors` in; one line for a missing one or one of another shape or dtype."""
        with torch.no_grad():
            for name, param in zip(self._names(prefix), self.parameters(), strict=True):
                tensor = tensors.get(name)
                if tensor is None:
                    raise ValueError(f"tensor {name} is missing")
                if tensor.dtype != torch.float32 or tensor.shape != param.shape:
                    raise ValueError(
                        f"tensor {name} is {tensor.dtype} {tuple(tensor.shape)}: must be float32 {tuple(param.shape)}"
                    )
                if not bool(torch.isfinite(tensor).all()):
                    raise ValueError(f"tensor {name} holds NaN or infinite values: must be finite")
                param.copy_(tensor)

    def _names(self, prefix: str) -> list[str]:
        layers = range(len(self.weights))
        return [f"{prefix}/w{layer}" for layer in layers] + [f"{prefix}/b{layer}" for layer in layers]


def layer_widths(tensors: Mapping[str, torch.Tensor], prefix: str) -> tuple[int, tuple[int, ...]]:
    """``(P, widths)`` of the network stored under ``prefix`` in ``tensors``, read from its weight shapes (one line if
    they do not chain)."""
    layers = 0
    while f"{prefix}/w{layers}" in tensors:
        layers += 1
    if not 2 <= layers <= MAX_LAYERS + 1:
        raise ValueError(f"tensors {prefix}/w0, w1, ... hold {layers} layers: must hold 2 to {MAX_LAYERS + 1}")
    shapes = [tuple(tensors[f"{prefix}/w{layer}"].shape) for layer in range(layers)]
    if any(len(shape) != 3 for shape in shapes):
        raise ValueError(f"tensors {prefix}/w* are {shapes}: each must be (processes, inputs, outputs)")
    processes = shapes[0][0]
    for before, after in zip(shapes[:-1], shapes[1:], strict=True):
        if after[0] != processes or after[1] != before[2]:
            raise ValueError(f"tensors {prefix}/w* are {shapes}: their layers do not chain")
    return processes, (shapes[0][1], *(shape[2] for shape in shapes))


# ---------------------------------------------------------------------- what every learner of networks shares
def clip_gradients(network: QNetwork, max_norm: float) -> None:
    """Scale each process's gradient of ``network`` to a norm of at most ``max_norm`` (the processes share no
    weight: each is clipped on its own)."""
    grads = [param.grad for param in network.parameters()]
    norms = torch.sqrt(sum(grad.pow(2).flatten(1).sum(1) for grad in grads))
    scale = (max_norm / (norms + 1e-6)).clamp_max(1.0)
    for grad in grads:
        grad.mul_(scale.view(-1, *([1] * (grad.ndim - 1))))


def optimizer_tensors(optimizer: torch.optim.Adam) -> dict[str, torch.Tensor]:
    """Adam's state as named tensors, ``optimizer/<i>.<key>`` for parameter ``i``, for an exact resume."""
    named = {}
    for index, state in optimizer.state_dict()["state"].items():
        for key, value in state.items():
            named[f"optimizer/{index}.{key}"] = value.detach().reshape(value.shape)
    return named


def load_optimizer_tensors(
    optimizer: torch.optim.Adam, params: Iterable[torch.Tensor], tensors: Mapping[str, torch.Tensor]
) -> None:
    """Give ``optimizer`` (over ``params``, in order) the state of :func:`optimizer_tensors`; one line for a missing
    or misshapen tensor."""
    state: dict[int, dict[str, Any]] = {}
    for index, param in enumerate(params):
        entry = {}
        for key, shape in (("step", ()), ("exp_avg", param.shape), ("exp_avg_sq", param.shape)):
            name = f"optimizer/{index}.{key}"
            tensor = tensors.get(name)
            if tensor is None:
                raise ValueError(f"tensor {name} is missing")
            if tensor.dtype != torch.float32 or tuple(tensor.shape) != tuple(shape):
                raise ValueError(
                    f"tensor {name} is {tensor.dtype} {tuple(tensor.shape)}: must be float32 {tuple(shape)}"
                )
            entry[key] = tensor.clone()
        state[index] = entry
    saved = optimizer.state_dict()
    optimizer.load_state_dict({"state": state, "param_groups": saved["param_groups"]})
