"""What a run will cost and whether it can work, checked before any compute: memory, and states to fit K."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Final

from pedrl.vq.kmeans import default_chunk_size

if TYPE_CHECKING:
    from pedrl.algos.phase import TrainerView

TABLE_COPIES: Final = 2
"""Q tables alive at once in the memory estimate: the phase's and the previous phase's (followed while gathering,
through a replication to the new agents in IN-VQQL that is freed before the new tables are made)."""
GATHER_COPIES: Final = 3
"""Copies of every gathered state in the memory estimate: as recorded, concatenated, and prepared for k-means."""
KMEANS_COPIES: Final = 4
"""Copies of the states one k-means fit holds: subsampled, standardised, weighted, and their nearest distances."""


def memory_needs(trainer: TrainerView) -> dict[str, float]:
    """Estimated bytes of a run's largest allocations, by what they hold: the worst phase of each.

    Q tables ``(R, A, K, 81)`` float32 (:data:`TABLE_COPIES` of them), the gathered states
    (``gather_trials x R E N x max_decisions`` rows of ``F`` float32 in each room, the ``mix`` rooms' included,
    :data:`GATHER_COPIES` copies), one k-means
    fit (``vq.max_states`` states, :data:`KMEANS_COPIES` copies, and a ``chunk_size x K`` block of scores) and
    one decision of the largest room (:meth:`pedrl.sim.RoomEnv.step_memory`).
    """
    tables = gathered = kmeans = room = 0
    chunk = trainer.vq.chunk_size or default_chunk_size(trainer.device)
    for phase in trainer.phases():
        env = trainer.env_for(phase.num_agents)
        entries = trainer.processes * trainer.num_tables(phase) * trainer.max_prototypes(phase) * env.num_actions
        tables = max(tables, TABLE_COPIES * entries * 4)
        rooms = trainer.processes * trainer.rooms_per_process
        trained_in = [room for _, room in trainer.rooms(env)]  # the phase's room and the mix rooms
        rows = phase.gather_trials * rooms * sum(room.num_agents for room in trained_in) * env.params.max_decisions
        gathered = max(gathered, rows * (GATHER_COPIES * env.num_features * 4 + 16))
        fit_rows = min(rows, trainer.vq.max_states)
        kmeans = max(kmeans, (KMEANS_COPIES * fit_rows * env.num_features + chunk * trainer.vq.num_prototypes) * 4)
        room = max(room, *(room_env.step_memory() for room_env in trained_in))
    return {"Q tables": tables, "gathered states": gathered, "k-means": kmeans, "room": room}


def check_gathering_yield(trainer: TrainerView) -> None:
    """Refuse, before any compute, a ``vq.num_prototypes`` that no gathering can reach: k-means needs a distinct
    state per prototype, and a phase records at most ``gather_trials x E x N x max_decisions`` states per
    process (``R`` times that for a shared quantizer), ``N`` the agents of its room and of every ``mix`` room (each
    gathered as :func:`memory_needs` counts it). Fewer distinct states than that (agents leave the room
    early) only shrink K, with a warning (:meth:`fit_quantizers`)."""
    for phase in trainer.phases():
        env = trainer.env_for(phase.num_agents)
        trained_in = [room.num_agents for _, room in trainer.rooms(env)]  # the phase's room and the mix rooms
        factors = {
            "algo.gather_trials": phase.gather_trials,
            "rooms_per_process": trainer.rooms_per_process,
            "agents": sum(trained_in),
            "env.max_decisions": env.params.max_decisions,
        }
        if not trainer.vq.per_process:
            factors = {"processes": trainer.processes, **factors}
        most = math.prod(factors.values())
        if most < trainer.vq.fit_states:
            scope = "for the shared quantizer" if not trainer.vq.per_process else "per process"
            product = " x ".join(
                agents_text(value, trained_in) if key == "agents" else f"{key}={value}"
                for key, value in factors.items()
            )
            key = "vq.num_prototypes" if trainer.vq.factors is None else "vq.factors.own.num_prototypes"
            raise ValueError(
                f"{key}={trainer.vq.fit_states} is invalid: phase {phase.index} gathers at most "
                f"{most} states {scope} ({product}) and k-means needs one per prototype: must be at most "
                f"{most}, or raise algo.gather_trials"
            )


def agents_text(count: int, rooms: list[int] | None = None) -> str:
    """``1 agent``, ``20 agents``; with the agents of several ``rooms``, ``26 agents (20 + 6 in the mix rooms)``."""
    text = f"{count} agent" if count == 1 else f"{count} agents"
    if rooms is not None and len(rooms) > 1:
        text += f" ({rooms[0]} + {' + '.join(str(n) for n in rooms[1:])} in the mix rooms)"
    return text
