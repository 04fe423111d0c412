"""How bodies move through one decision: a motion model is one small frozen dataclass of its parameters, in the module
of its kernels, and the room takes one (``RoomEnv(motion=...)``; ``env.motion`` in a config, chosen by name).

- :mod:`~pedrl.sim.motion.sequential`: :class:`Stop` (contact ``stop``, the paper's reading, movers in turn),
  :func:`move_agents_sequential`, kernel in :mod:`~pedrl.sim.motion.sequential_kernel`;
- :mod:`~pedrl.sim.motion.simultaneous`: :class:`Simultaneous` (contact ``stop``, every mover checked at once),
  :func:`move_agents`;
- :mod:`~pedrl.sim.motion.sliding`: :class:`Slide`, :class:`Headway`, :class:`Yield` and :class:`Continuous` (the
  walking layer), :func:`move_agents_sliding`, kernel in :mod:`~pedrl.sim.motion.sliding_kernel`.

A model with a kernel dispatches under its plain name (the kernel on the CPU, its torch twin ``*_torch`` elsewhere);
the kernel returns the torch code's numbers to the bit. :mod:`~pedrl.sim.motion.common` holds what they share: the
:class:`MotionModel` base, the :class:`Movement` they return and the one enumeration of the collision rules and
contact models. :data:`MOTION_MODELS` names every model; :func:`motion_from_config` builds one from its config node.
"""

from collections.abc import Mapping
from dataclasses import fields
from typing import Any, Final

from pedrl.common.checks import shown
from pedrl.sim.motion.common import (
    COLLISION_ORDERS,
    COLLISION_RULES,
    CONTACT_MODELS,
    MOTION_KEY,
    PAIR_MARGIN,
    Motion,
    MotionModel,
    Movement,
    Steering,
)
from pedrl.sim.motion.sequential import Stop, move_agents_sequential, move_agents_sequential_torch
from pedrl.sim.motion.simultaneous import Simultaneous, move_agents
from pedrl.sim.motion.sliding import (
    Continuous,
    Headway,
    Slide,
    SlidingMotion,
    Yield,
    headway_factors,
    move_agents_sliding,
    move_agents_sliding_torch,
)

MOTION_MODELS: Final[dict[str, type[MotionModel]]] = {
    model.name: model for model in (Stop, Simultaneous, Slide, Headway, Yield, Continuous)
}
"""Every motion model by its config name (``env.motion.name``)."""


def motion_from_config(node: Any) -> MotionModel:
    """The motion model of a config node ``{"name": <model>, <field>: <value>, ...}`` (``env.motion``; a missing
    field takes the model's default, ``steering`` is a mapping of :class:`Steering`'s fields). Nothing is imported or
    instantiated by a name in it but the models of :data:`MOTION_MODELS`.

    Raises:
        ValueError: one line naming the config key (``env.motion.time_gap``) and what is allowed.
    """
    names = ", ".join(MOTION_MODELS)
    if not isinstance(node, Mapping):
        raise ValueError(
            f"{MOTION_KEY}={shown(node)} is invalid: must be a motion model chosen by name (motion=<name> on the"
            f" command line: {names}) with its settings"
        )
    name = node.get("name")
    if not isinstance(name, str) or name not in MOTION_MODELS:
        raise ValueError(f"{MOTION_KEY}.name={shown(name)} is invalid: must be one of {names}")
    model = MOTION_MODELS[name]
    settings = {key: value for key, value in node.items() if key != "name"}
    allowed = [item.name for item in fields(model)]
    for key in settings:
        if key not in allowed:
            listed = ", ".join(allowed) or "none"
            raise ValueError(f"{MOTION_KEY}.{key} is not a setting of motion {name!r}: its settings are {listed}")
    if isinstance(settings.get("steering"), Mapping):
        steering = settings["steering"]
        allowed = [item.name for item in fields(Steering)]
        for key in steering:
            if key not in allowed:
                raise ValueError(f"{MOTION_KEY}.steering.{key} is not a setting of the steering: {', '.join(allowed)}")
        settings["steering"] = Steering(**steering)
    return model(**settings)


__all__ = [
    "COLLISION_ORDERS",
    "COLLISION_RULES",
    "CONTACT_MODELS",
    "MOTION_KEY",
    "MOTION_MODELS",
    "PAIR_MARGIN",
    "Continuous",
    "Headway",
    "Motion",
    "MotionModel",
    "Movement",
    "Simultaneous",
    "Slide",
    "SlidingMotion",
    "Steering",
    "Stop",
    "Yield",
    "headway_factors",
    "motion_from_config",
    "move_agents",
    "move_agents_sequential",
    "move_agents_sequential_torch",
    "move_agents_sliding",
    "move_agents_sliding_torch",
]
