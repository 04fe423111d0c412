"""A learned network (a Q-network, or PPO's actor) as an ONNX model, with its observation and action contract.

``pedrl-export checkpoint=<a dqn or ppo checkpoint> out=policy.onnx`` writes ``policy.onnx`` and
``policy.onnx.json``. The model takes what :class:`pedrl.sim.RoomEnv` gives, nothing prepared: ``obs`` ``(B, F)``
float32 (an agent's deictic state, the features in the order ``contract["observation"]["features"]`` names) and
``num_sensed`` ``(B,)`` int64 (the neighbours sensed), for a network that reads them ``neighbour_velocity``
``(B, k, 2)`` float32 (the room's ``info["neighbour_velocity"]``), and returns ``q_values`` ``(B, 81)`` float32
(the Q-values; PPO's actor's logits) and ``action`` ``(B,)`` int64 (the best, or most probable, one); a continuous
policy's model (PPO's ``algo.actions=continuous``) returns ``means`` ``(B, 2)`` (the actor's outputs) and ``command``
``(B, 2)`` (their squash: the speed ratio and the heading offset from the goal bearing, as ``RoomEnv.step`` takes them).
The distance transform, the standardisation and the neighbour presence flags are inside the graph. The JSON file
states the contract: the inputs and outputs, the features, the action codec (the action frame, the speed and turn of
each action), the decision length, and the room settings the network learned in. onnxruntime runs it without torch
or pedrl (``tests/test_onnx_export.py`` checks a round trip against :meth:`pedrl.rl.NeuralPolicy.act`).
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path
from typing import Any, Final

import torch

from pedrl.common.checks import check_integer
from pedrl.io.files import replace_atomically
from pedrl.rl.network import head_values
from pedrl.rl.neural import (
    MAX_OFFSET,
    SPEED_OVERSHOOT,
    ContinuousPolicy,
    NeuralPolicy,
    command_means,
    company_column,
    squash,
)
from pedrl.sim.sensing import distance_indices, feature_names

OPSET: Final = 18
CONTRACT_VERSION: Final = 1


class _Exported(torch.nn.Module):
    """Process ``process``'s network of ``policy`` with its input preparation, as one graph."""

    def __init__(self, policy: NeuralPolicy, process: int) -> None:
        super().__init__()
        settings = policy.encoder.settings
        mask = torch.zeros(settings.num_features, dtype=torch.bool)
        if settings.distance_transform == "log":
            mask[distance_indices(settings.num_neighbours, settings.num_walls)] = True
        self.register_buffer("log_mask", mask)
        self.register_buffer("mean", policy.mean.detach().cpu().clone())
        self.register_buffer("std", policy.std.detach().cpu().clone())
        self.register_buffer("slots", torch.arange(settings.num_neighbours))
        self.company_column = company_column(settings)
        network = policy.network
        self.head, self.continuous = network.head, isinstance(policy, ContinuousPolicy)
        self.weights = [w[process].detach().cpu().clone() for w in network.weights]
        self.biases = [b[process, 0].detach().cpu().clone() for b in network.biases]
        for layer, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            self.register_buffer(f"w{layer}", weight)
            self.register_buffer(f"b{layer}", bias)

    def forward(
        self, obs: torch.Tensor, num_sensed: torch.Tensor, neighbour_velocity: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        prepared = torch.where(self.log_mask, torch.log1p(torch.clamp(obs, min=0.0)), obs)
        present = (self.slots.unsqueeze(0) < num_sensed.unsqueeze(1)).to(obs.dtype)
        parts = [(prepared - self.mean) / self.std, present]
        if neighbour_velocity is not None:
            parts.append(neighbour_velocity.flatten(1))
        x = inputs = torch.cat(parts, dim=1)
        last = len(self.weights) - 1
        for layer in range(last + 1):
            x = x @ getattr(self, f"w{layer}") + getattr(self, f"b{layer}")
            if layer < last:
                x = torch.relu(x)
        if self.continuous:
            x = command_means(x, inputs, self.company_column)
            return x, squash(x)
        x = head_values(self.head, x)
        return x, x.argmax(dim=1)


def input_contract(policy: NeuralPolicy) -> dict[str, Any]:
    """The model's inputs, in order: the observations, the neighbours sensed and, for a policy that reads them, the
    neighbours' velocities."""
    settings = policy.encoder.settings
    inputs: dict[str, Any] = {
        "obs": {"dtype": "float32", "shape": ["batch", settings.num_features]},
        "num_sensed": {"dtype": "int64", "shape": ["batch"], "range": [0, settings.num_neighbours]},
    }
    if policy.neighbour_velocity:
        inputs["neighbour_velocity"] = {
            "dtype": "float32",
            "shape": ["batch", settings.num_neighbours, 2],
            "meaning": "each sensed neighbour's velocity along and across the line to the goal (m/s), 0 in empty "
            "slots: RoomEnv's info['neighbour_velocity']",
        }
    return inputs


def contract(policy: NeuralPolicy, room: Any, process: int) -> dict[str, Any]:
    """The observation and action contract of the exported model (module docstring), as plain JSON values."""
    settings = policy.encoder.settings
    config = policy.metadata.get("config", {})
    speeds = [float(v) for v in room.speed_changes.tolist()]
    turns = [float(v) for v in room.turn_changes.tolist()]
    continuous = isinstance(policy, ContinuousPolicy)
    return {
        "contract_version": CONTRACT_VERSION,
        "producer": "pedrl-export",
        "algo": policy.metadata.get("algo", "dqn"),
        "process": process,
        "processes": policy.num_processes,
        "inputs": input_contract(policy),
        "outputs": command_outputs()
        if continuous
        else {
            "q_values": {
                "dtype": "float32",
                "shape": ["batch", len(speeds) * len(turns)],
                "meaning": "the actor's logits" if policy.metadata.get("algo") == "ppo" else "Q-values",
            },
            "action": {"dtype": "int64", "shape": ["batch"], "meaning": "argmax of q_values"},
        },
        "observation": {
            "features": feature_names(settings.num_neighbours, settings.num_walls),
            "units": "metres, metres per second and radians, as pedrl.sim.RoomEnv observes them; empty slots 0",
            "num_neighbours": settings.num_neighbours,
            "num_walls": settings.num_walls,
            "prepared_inside": "log(1 + d) of every distance (distance_transform=log), standardised, presence flags",
            "distance_transform": settings.distance_transform,
        },
        "actions": command_codec(room)
        if continuous
        else {
            "count": len(speeds) * len(turns),
            "index": "speed_index * 9 + turn_index",
            "frame": room.params.action_frame,
            "speed": speeds,
            "turn": turns,
            "speed_meaning": "the new speed (m/s)"
            if room.params.action_frame == "goal"
            else "the change of speed (m/s)",
            "turn_meaning": "the heading's offset from the line to the goal (rad)"
            if room.params.action_frame == "goal"
            else "the change of heading (rad)",
            "max_speed": float(room.params.max_speed),
            "decision_length_s": float(room.params.decision_length),
        },
        "room": config.get("env", {}),
        "scenario": config.get("scenario", {}),
    }


def command_outputs() -> dict[str, Any]:
    """A continuous policy's outputs: the actor's means and the command they squash into."""
    return {
        "means": {"dtype": "float32", "shape": ["batch", 2], "meaning": "the actor's outputs (the Gaussian's means)"},
        "command": {
            "dtype": "float32",
            "shape": ["batch", 2],
            "meaning": f"[0.5 + {0.5 + SPEED_OVERSHOOT} tanh(means[0]), {MAX_OFFSET!r} tanh(means[1])]: the speed "
            "ratio (clipped to [0, 1] by the room) and the heading offset from the line to the goal (rad)",
        },
    }


def command_codec(room: Any) -> dict[str, Any]:
    """What a continuous policy's command does in ``room`` (RoomEnv.step's float commands, the ``goal`` frame)."""
    return {
        "kind": "continuous",
        "frame": room.params.action_frame,
        "command": ["speed_ratio", "heading_offset"],
        "speed_meaning": "the new speed: clip(speed_ratio, 0, 1) * max_speed (m/s)",
        "turn_meaning": "the new heading: the bearing of the line to the goal + heading_offset (rad)",
        "max_speed": float(room.params.max_speed),
        "decision_length_s": float(room.params.decision_length),
    }


def export_onnx(policy: NeuralPolicy, room: Any, out: str | Path, *, process: int = 0) -> Path:
    """Write process ``process``'s network of ``policy`` to ``out`` (``.onnx``) and its contract to ``out.json``, each
    atomically; ``room`` is a room of the policy's training config (its action codec)."""
    check_integer("process", process, minimum=0, maximum=policy.num_processes - 1)
    module = _Exported(policy, process).eval()
    settings = policy.encoder.settings
    example = (torch.zeros(2, settings.num_features), torch.zeros(2, dtype=torch.int64))
    if policy.neighbour_velocity:
        example = (*example, torch.zeros(2, settings.num_neighbours, 2))
    names = list(input_contract(policy))

    batch = torch.export.Dim("batch")

    def write(path: Path) -> None:
        quiet = logging.getLogger("torch.onnx")  # its registry logs every torchvision operator it cannot find
        level = quiet.level
        quiet.setLevel(logging.ERROR)
        with warnings.catch_warnings():  # the exporter's notes on its own internals (the batch axes are one, ...)
            warnings.simplefilter("ignore", UserWarning)
            warnings.simplefilter("ignore", FutureWarning)
            torch.onnx.export(
                module,
                example,
                str(path),
                input_names=names,
                output_names=list(command_outputs()) if module.continuous else ["q_values", "action"],
                dynamic_shapes=tuple({0: batch} for _ in names),
                opset_version=OPSET,
                dynamo=True,
                verbose=False,
                optimize=True,
                external_data=False,  # one file: the weights inside it
            )
        quiet.setLevel(level)

    out = replace_atomically(out, write)
    text = json.dumps(contract(policy, room, process), indent=2)
    replace_atomically(out.with_name(out.name + ".json"), lambda path: path.write_text(text))
    return out


def process_note(contract_path: str | Path) -> str | None:
    """For a model written from a checkpoint of several learning processes, one line saying that it is one process's
    network, so that it agrees with pedrl's crowd only in the replicas of that process (replica ``i`` acts with network
    ``i mod P``), and how to write another; None for a checkpoint of one process."""
    contract = json.loads(Path(contract_path).read_text())
    processes, process = contract.get("processes", 1), contract["process"]
    if processes <= 1:
        return None
    return (
        f"the network of process {process} of {processes}: pedrl's crowd acts with network i mod {processes} in"
        f" replica i, so this model agrees with the replicas of process {process} only (process=<index> writes another)"
    )
