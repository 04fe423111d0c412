"""How bodies move through one decision: one module per motion model, each with its numba twin beside it.

- :mod:`~pedrl.sim.motion.simultaneous`: ``collision_rule=simultaneous`` (contact ``stop``), :func:`move_agents`;
- :mod:`~pedrl.sim.motion.sequential`: ``collision_rule=sequential`` with contact ``stop`` (the paper's reading),
  :func:`move_agents_sequential`, kernel in :mod:`~pedrl.sim.motion.sequential_kernel`;
- :mod:`~pedrl.sim.motion.sliding`: contacts ``slide``, ``headway`` and ``yield``, :func:`move_agents_sliding`,
  kernel in :mod:`~pedrl.sim.motion.sliding_kernel`.

A model with a kernel dispatches under its plain name (the kernel on the CPU, its torch twin ``*_torch`` elsewhere);
the kernel returns the torch code's numbers to the bit. :mod:`~pedrl.sim.motion.common` holds what they share: the
:class:`Movement` they return and the one enumeration of the collision rules and contact models.
"""

from pedrl.sim.motion.common import COLLISION_RULES, CONTACT_MODELS, PAIR_MARGIN, Motion, Movement, Steering
from pedrl.sim.motion.sequential import move_agents_sequential, move_agents_sequential_torch
from pedrl.sim.motion.simultaneous import move_agents
from pedrl.sim.motion.sliding import (
    SlidingMotion,
    headway_factors,
    move_agents_sliding,
    move_agents_sliding_torch,
)

__all__ = [
    "COLLISION_RULES",
    "CONTACT_MODELS",
    "PAIR_MARGIN",
    "Motion",
    "Movement",
    "SlidingMotion",
    "Steering",
    "headway_factors",
    "move_agents",
    "move_agents_sequential",
    "move_agents_sequential_torch",
    "move_agents_sliding",
    "move_agents_sliding_torch",
]
