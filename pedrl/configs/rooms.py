"""The rooms a config describes: its own (:func:`env_factory`) and those of its ``mix`` (:func:`mix_rooms`).

Rooms are built by calling :class:`pedrl.sim.RoomEnv` with the config's plain values, which its constructor
validates like any typed value; nothing is ever instantiated from a config node.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import fields
from typing import Any, Final, NamedTuple

from pedrl.common.checks import shown
from pedrl.configs.motion import check_no_flat_keys
from pedrl.configs.names import ENV_CLASSES
from pedrl.scenarios import build_scenario, inline_geometry
from pedrl.sim import RoomEnv, RoomParams
from pedrl.sim.motion import motion_from_config

ENV_RUN_ARGUMENTS: Final = ("num_replicas", "num_agents", "device")
"""Room arguments supplied at run time (not config values); the walkable area comes from the ``scenario`` config."""
ROOM_SETTINGS: Final = tuple(item.name for item in fields(RoomParams))
"""The ``env`` keys of the room's settings: the fields of :class:`pedrl.sim.RoomParams`."""
AREA_SETTINGS: Final = ("width", "length", "door_width")
"""``env`` keys that describe the walkable area, not the room: the sizes of the paper's room (``scenario=paper_room``,
:func:`pedrl.scenarios.paper_room`)."""
MAX_MIX: Final = 16
"""Most rooms of a ``mix`` (training across scenarios)."""
MAX_MIX_AGENTS: Final = 10_000
"""Most agents of a room of a ``mix``."""


class TrainingRoom(NamedTuple):
    """A room a run trains in besides its scenario's (``mix``): its label, its factory (:func:`env_factory`), its
    agents, its ``mix`` entry as a checkpoint stores it (a WKT file replaced by its text) and its longest distance
    (m, the room's diagonal)."""

    label: str
    factory: Callable[..., RoomEnv]
    num_agents: int
    config: dict[str, Any]
    max_distance: float


def env_factory(
    env: Mapping[str, Any], scenario: Mapping[str, Any] | None = None, *, files: bool = True
) -> Callable[..., RoomEnv]:
    """The room of the ``env`` config in the ``scenario``: ``factory(num_replicas=, num_agents=, device=)`` builds it.

    The scenario (``None``: the paper's room of the ``env`` keys) is built once, with shapely; each room is
    :meth:`pedrl.scenarios.Scenario.room`: validated, then its agents checked against the spawn areas.
    ``files=False`` (a config stored in a checkpoint) opens no file: its ``scenario.geometry`` must be WKT text.

    Raises:
        ValueError: one line, for a key the room does not take or a bad scenario (values are validated when the room
            is built).
    """
    if isinstance(env, Mapping):
        check_no_flat_keys(env)
    settings = config_settings("env", env, ENV_CLASSES, supplied=ENV_RUN_ARGUMENTS, names=ROOM_SETTINGS + AREA_SETTINGS)
    built = build_scenario(scenario, room=settings, files=files)
    room = room_keywords(settings)

    def factory(*, num_replicas: int, num_agents: int, device: str | Any = "cpu") -> RoomEnv:
        return built.room(num_replicas=num_replicas, num_agents=num_agents, device=device, **room)

    factory.scenario = built  # type: ignore[attr-defined]
    return factory


def room_keywords(env: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword settings of a room (:meth:`pedrl.scenarios.Scenario.room`) of an ``env`` config or mapping: its
    keys but ``_target_`` and the walkable area's (:data:`AREA_SETTINGS`, the scenario's), its ``motion`` node the
    motion model it names (:func:`pedrl.sim.motion.motion_from_config`).

    Raises:
        ValueError: one line, for a flat key of the motion model (:func:`pedrl.configs.motion.old_keys_advice`) or
            a bad ``motion`` node.
    """
    check_no_flat_keys(env)
    settings = {key: value for key, value in env.items() if key != "_target_" and key not in AREA_SETTINGS}
    if isinstance(settings.get("motion"), Mapping):
        settings["motion"] = motion_from_config(settings["motion"])
    return settings


def config_settings(
    section: str,
    node: Any,
    classes: Mapping[str, type],
    *,
    supplied: tuple[str, ...],
    names: tuple[str, ...] | None = None,
) -> dict[str, Any]:
    """The settings of the ``section`` node of a config (``env``) for the class its ``_target_`` selects among
    ``classes``: every other key, each a keyword parameter of that class but the ``supplied`` ones, or one of
    ``names`` where they are given (the room's settings and its area's, for ``env``).

    Raises:
        ValueError: one line, for a node that is not a mapping, an unknown ``_target_`` or a key the class does
            not take.
    """
    if not isinstance(node, Mapping):
        raise ValueError(f"{section}={node!r} is invalid: must be a mapping with a _target_")
    target = node.get("_target_")
    if not isinstance(target, str) or target not in classes:
        raise ValueError(f"{section}._target_={target!r} is invalid: must be one of {', '.join(classes)}")
    allowed = list(names) if names is not None else [n for n in setting_names(classes[target]) if n not in supplied]
    settings = {key: value for key, value in node.items() if key != "_target_"}
    for key in settings:
        if key not in allowed:
            raise ValueError(f"{section}.{key} is not a setting of {target}: allowed: {', '.join(allowed)}")
    return settings


def setting_names(cls: type) -> list[str]:
    """The fields of ``cls.settings_class`` (a learner whose settings are a record), else the keyword parameters of
    ``cls``, following ``**kwargs`` up to the base classes' constructors."""
    record = getattr(cls, "settings_class", None)
    if record is not None:
        return [item.name for item in fields(record)]
    names: list[str] = []
    for klass in cls.__mro__:
        if "__init__" not in vars(klass) or klass is object:
            continue
        parameters = inspect.signature(klass.__init__).parameters.values()
        names += [p.name for p in parameters if p.name != "self" and p.kind is p.KEYWORD_ONLY and p.name not in names]
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            break
    return names


def mix_rooms(env: Mapping[str, Any], mix: Any, *, home: str = "room", files: bool = True) -> list[TrainingRoom]:
    """The rooms of a ``mix`` config: a list of scenario configs (``name`` and the builder's keys, as in
    ``conf/scenario/``), each with the ``agents`` it holds; each room is the ``env`` config's, in its scenario.

    Labels (the TensorBoard tags and the ``room`` column of ``learning_curve.csv``) are ``<name>_<agents>``, with
    ``_<index>`` added where two would be the same; the run's own room is labelled ``home``, its scenario's name.

    Raises:
        ValueError: one line naming ``mix[i]`` and the bad value.
    """
    if mix is None:
        return []
    if not isinstance(mix, list | tuple):
        raise ValueError(
            f"mix={shown(mix)} is invalid: must be a list of scenarios, e.g. [{{name: corridor, agents: 40}}]"
        )
    if len(mix) > MAX_MIX:
        raise ValueError(f"mix holds {len(mix)} rooms: at most {MAX_MIX}")
    rooms, labels = [], {home}
    for index, entry in enumerate(mix):
        where = f"mix[{index}]"
        if not isinstance(entry, Mapping) or not isinstance(entry.get("name"), str):
            raise ValueError(
                f"{where}={shown(entry)} is invalid: must be a scenario config with a name and agents, e.g. "
                "{name: corridor, agents: 40}"
            )
        agents = entry.get("agents")
        if isinstance(agents, bool) or not isinstance(agents, int) or not 1 <= agents <= MAX_MIX_AGENTS:
            raise ValueError(f"{where}.agents={shown(agents)} is invalid: must be an integer in [1, {MAX_MIX_AGENTS}]")
        try:
            scenario = inline_geometry({key: value for key, value in entry.items() if key != "agents"}, files=files)
            factory = env_factory(env, scenario, files=files)
            max_distance = factory(num_replicas=1, num_agents=agents).max_distance  # the agents must fit
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from None
        label = f"{scenario['name']}_{agents}"
        label = label if label not in labels else f"{label}_{index}"
        labels.add(label)
        rooms.append(TrainingRoom(label, factory, agents, {**scenario, "agents": agents}, max_distance))
    return rooms
