"""The motion model of a config (``env.motion``: a model chosen by name, with its fields), and the flat keys that
described it before (``env.contact``, ``env.collision_rule``, ``env.collision_order``, ``env.time_gap``,
``env.motion: step|continuous``, ``env.time_step``, ``env.neighbour_repulsion``, ``env.wall_repulsion``).

A config stored in an older checkpoint holds the flat keys: :func:`flat_motion` maps them onto the model they gave,
the same room to the bit (:func:`pedrl.configs.stored_env` applies it). A config typed today that holds one is refused
with the model and fields it means (:func:`old_keys_advice`), on the command line as in a file.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any, Final

from pedrl.common.checks import check_choice, check_real, shown
from pedrl.sim.motion import (
    COLLISION_ORDERS,
    COLLISION_RULES,
    CONTACT_MODELS,
    MOTION_MODELS,
    Continuous,
    MotionModel,
    Simultaneous,
    Steering,
    Stop,
    motion_from_config,
)

FLAT_DEFAULTS: Final = {
    "contact": "stop",
    "collision_rule": "sequential",
    "collision_order": "random",
    "time_gap": 1.0,
    "motion": "step",
    "time_step": 0.05,
    "neighbour_repulsion": [8.0, 0.1],
    "wall_repulsion": [5.0, 0.02],
}
"""The flat keys of the motion model that configs held before ``env.motion`` named a model, with the room's defaults
then (a checkpoint older than a key had its default: ``HISTORICAL_VALUES``)."""
FLAT_KEYS: Final = tuple(FLAT_DEFAULTS)
WALKING_LAYERS: Final = ("step", "continuous")
"""The values of the flat ``motion`` key: the step model, or the continuous walking layer."""
ADVICE: Final = 'docs/configuration.md, "Motion models"'


def is_flat(env: Mapping[str, Any]) -> bool:
    """Whether the ``env`` config describes its motion model by the flat keys (no ``motion`` mapping)."""
    return not isinstance(env.get("motion"), Mapping) or any(key in env for key in FLAT_KEYS if key != "motion")


def flat_motion(settings: Mapping[str, Any]) -> MotionModel:
    """The motion model the flat keys in ``settings`` gave (a key it lacks: :data:`FLAT_DEFAULTS`), checked as the room
    checked them: ``continuous`` needs contact ``headway`` or ``yield``, every contact rule but ``stop`` the
    sequential rule; the keys a model does not read (the order of the simultaneous rule, the time gap of ``stop``) are
    dropped, as the room ignored them.

    Raises:
        ValueError: one line naming the flat key and what is allowed.
    """
    flat = {**FLAT_DEFAULTS, **{key: settings[key] for key in FLAT_KEYS if key in settings}}
    contact = check_choice("contact", flat["contact"], CONTACT_MODELS)
    rule = check_choice("collision_rule", flat["collision_rule"], COLLISION_RULES)
    order = check_choice("collision_order", flat["collision_order"], COLLISION_ORDERS)
    layer = check_choice("motion", flat["motion"], WALKING_LAYERS)
    if contact != "stop" and rule != "sequential":
        raise ValueError(
            f"collision_rule={rule!r} is invalid with contact={contact!r}: the slide, headway and yield rules resolve"
            " movers in turn (collision_rule: sequential; it applies to contact=stop only)"
        )
    time_gap = check_real("time_gap", flat["time_gap"], unit="s", positive=True)
    if layer == "continuous":
        if contact not in ("headway", "yield"):
            raise ValueError(
                f"contact={contact!r} is invalid with motion='continuous': it walks by the collision-free speed rule"
                " (contact: headway or yield)"
            )
        steering = Steering(*_pair("neighbour_repulsion", flat), *_pair("wall_repulsion", flat))
        return Continuous(
            contact=contact, time_gap=time_gap, order=order, time_step=flat["time_step"], steering=steering
        )
    if contact == "stop":
        return Stop(order=order) if rule == "sequential" else Simultaneous()
    model = MOTION_MODELS[contact]
    return model(order=order) if contact == "slide" else model(time_gap=time_gap, order=order)


def _pair(name: str, flat: Mapping[str, Any]) -> tuple[Any, Any]:
    """A flat ``[strength, range]`` pair, else one line naming it."""
    value = flat[name]
    if isinstance(value, str | bytes) or not isinstance(value, list | tuple) or len(value) != 2:
        raise ValueError(f"{name}={shown(value)} is invalid: must be [strength, range] (strength >= 0, range > 0 m)")
    return value[0], value[1]


def flat_keys_of(model: MotionModel) -> dict[str, Any]:
    """The flat keys that give ``model`` (:func:`flat_motion` of them is ``model``): the base onto which a flat key
    typed today is read, so that ``env.time_gap=0.4`` on a run of ``motion=continuous`` means that model's gap."""
    own = {item.name for item in fields(model)}  # type: ignore[arg-type]
    flat: dict[str, Any] = {"collision_order": model.order if "order" in own else FLAT_DEFAULTS["collision_order"]}
    if isinstance(model, Simultaneous):
        flat["collision_rule"] = "simultaneous"
    elif isinstance(model, Continuous):
        steering = model.steering
        flat.update(
            motion="continuous",
            contact=model.contact,
            time_gap=model.time_gap,
            time_step=model.time_step,
            neighbour_repulsion=[steering.neighbour_strength, steering.neighbour_range],
            wall_repulsion=[steering.wall_strength, steering.wall_range],
        )
    else:  # the step models, each named after its contact rule
        flat["contact"] = model.name
        if "time_gap" in own:
            flat["time_gap"] = model.time_gap
    return flat


def overrides(model: MotionModel) -> str:
    """The command line that chooses ``model``: ``motion=<name>`` and each field that differs from the model's
    default (``env.motion.order=door_first``)."""
    default = type(model)()
    words = [f"motion={model.name}"]
    for item in fields(model):  # type: ignore[arg-type]
        value, base = getattr(model, item.name), getattr(default, item.name)
        if isinstance(value, Steering):
            words += [
                f"env.motion.steering.{part.name}={getattr(value, part.name):g}"
                for part in fields(value)
                if getattr(value, part.name) != getattr(base, part.name)
            ]
        elif value != base:
            words.append(
                f"env.motion.{item.name}={value:g}" if isinstance(value, float) else f"env.motion.{item.name}={value}"
            )
    return " ".join(words)


def old_keys_advice(env: Mapping[str, Any], where: str = "env.", base: MotionModel | None = None) -> str:
    """One line for a config that names the motion model by its flat keys (``where`` prefixes them): the model they
    mean and how to choose it now; or, where they do not make a model, why. ``base``: the model the rest of the
    config chooses (``motion=continuous``), which the flat keys change (None: the flat keys' own defaults)."""
    given = {key: env[key] for key in FLAT_KEYS if key in env and not isinstance(env[key], Mapping)}
    named = ", ".join(f"{where}{key}={shown(value)}" for key, value in given.items())
    if list(given) == ["motion"] and given["motion"] in MOTION_MODELS:  # env.motion=<name>: a model's name
        return (
            f"{named} is invalid: env.motion is the motion model, chosen by name with motion={given['motion']} on the"
            f" command line (its settings: env.motion.<key>; {ADVICE})"
        )
    try:
        model = flat_motion({**(flat_keys_of(base) if base is not None else {}), **given})
    except ValueError as err:
        return f"{named}: old keys of the motion model, and {err} ({ADVICE})"
    return (
        f"{named}: old keys of the motion model, which is chosen by name now: {overrides(model)} on the command line,"
        f" {model!r} in Python ({ADVICE})"
    )


def command_line_advice(key: str, typed: Mapping[str, Any], motion: Any = None) -> str | None:
    """One line for an override of a flat key of the motion model on the command line (``env.contact=yield``, which
    the config no longer holds): the model it means and how to choose it now; None for any other key.

    ``typed``: the command line's overrides, key to value as Hydra reads them (``env.time_gap=4e-1`` is 0.4). The flat
    keys change the model the rest of the command line chooses: ``motion`` (the composed ``env.motion`` node), else
    its ``motion=<name>``, else the flat keys' defaults (the step model)."""
    section, _, name = key.partition(".")
    if section != "env" or name not in FLAT_KEYS or name == "motion":
        return None
    given = {written[4:]: value for written, value in typed.items() if _is_flat_key(written)}
    chosen = typed.get("motion")
    base = _chosen_model(motion) or _chosen_model({"name": chosen} if isinstance(chosen, str) else None)
    return old_keys_advice(given or {name: FLAT_DEFAULTS[name]}, base=base)


def _is_flat_key(written: str) -> bool:
    return written.startswith("env.") and written[4:] in FLAT_KEYS


def _chosen_model(node: Any) -> MotionModel | None:
    """The motion model of an ``env.motion`` node, None for none or a bad one (told by its own check)."""
    if not isinstance(node, Mapping):
        return None
    try:
        return motion_from_config(node)
    except ValueError:
        return None


def check_no_flat_keys(env: Mapping[str, Any], where: str = "env.") -> None:
    """One-line ``ValueError`` (:func:`old_keys_advice`) for a config typed today that holds a flat key of the motion
    model, or an ``env.motion`` that is a string (``env.motion=continuous`` replaces the model's node)."""
    if any(key in env for key in FLAT_KEYS if key != "motion") or isinstance(env.get("motion"), str):
        raise ValueError(old_keys_advice(env, where, _chosen_model(env.get("motion"))))


__all__ = [
    "FLAT_DEFAULTS",
    "FLAT_KEYS",
    "WALKING_LAYERS",
    "flat_motion",
    "check_no_flat_keys",
    "command_line_advice",
    "flat_keys_of",
    "is_flat",
    "old_keys_advice",
    "overrides",
]
