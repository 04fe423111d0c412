"""What a config may hold, typed or stored in a file, and the room it describes: no trainer is imported here.

A config (typed by a user, or stored in a checkpoint that someone shared) never names code: ``env._target_`` and
``algo._target_`` select one of the known classes, and every other ``_target_``, and every other Hydra
instantiation key (``_partial_``, ``_args_``, ``_recursive_``, ...), anywhere in the config, is refused. Rooms are
then built by calling :class:`pedrl.sim.RoomEnv` with the config's plain values, which its constructor validates
like any typed value; nothing is ever instantiated from a config node but a motion model, chosen by its name among
the known ones (``env.motion.name``, :data:`pedrl.sim.motion.MOTION_MODELS`). The trainers a config may name are listed
here by name (:data:`ALGO_TARGETS`); :mod:`pedrl.algos.registry` maps them to their classes.

A config stored in a checkpoint is also bounded before anything walks it (:func:`check_stored_config`).

- :mod:`pedrl.configs.names`: the classes a config may name, and the check that it names no other code;
- :mod:`pedrl.configs.rooms`: the rooms a config describes (:func:`env_factory`, :func:`mix_rooms`);
- :mod:`pedrl.configs.stored`: a config stored in a file: its bounds, and the values of its time for keys added
  since (:data:`HISTORICAL_VALUES`, :func:`stored_env`, :func:`stored_value`);
- :mod:`pedrl.configs.embed`: a checkpoint that names its room's WKT file re-exported with the room in it;
- :mod:`pedrl.configs.motion`: the motion model of a config (``env.motion``, chosen by name), and the flat keys that
  described it before (old checkpoints map onto the model they gave; a config typed today is told the new spelling).
"""

from pedrl.configs.embed import embed_geometry
from pedrl.configs.names import ALGO_TARGETS, ENV_CLASSES, KNOWN_TARGETS, VOID_FEATURES_DEFAULTS, check_names_no_code
from pedrl.configs.rooms import (
    AREA_SETTINGS,
    ENV_RUN_ARGUMENTS,
    MAX_MIX,
    MAX_MIX_AGENTS,
    ROOM_SETTINGS,
    TrainingRoom,
    config_settings,
    env_factory,
    mix_rooms,
    room_keywords,
    setting_names,
)
from pedrl.configs.stored import (
    HISTORICAL_VALUES,
    MAX_CONFIG_DEPTH,
    MAX_CONFIG_STRING,
    MAX_CONFIG_VALUES,
    check_stored_config,
    checked_config,
    current_form,
    stored_env,
    stored_value,
)

__all__ = [
    "ALGO_TARGETS",
    "AREA_SETTINGS",
    "ENV_CLASSES",
    "ENV_RUN_ARGUMENTS",
    "HISTORICAL_VALUES",
    "KNOWN_TARGETS",
    "MAX_CONFIG_DEPTH",
    "MAX_CONFIG_STRING",
    "MAX_CONFIG_VALUES",
    "MAX_MIX",
    "MAX_MIX_AGENTS",
    "ROOM_SETTINGS",
    "VOID_FEATURES_DEFAULTS",
    "TrainingRoom",
    "check_names_no_code",
    "check_stored_config",
    "checked_config",
    "current_form",
    "config_settings",
    "embed_geometry",
    "env_factory",
    "mix_rooms",
    "room_keywords",
    "setting_names",
    "stored_env",
    "stored_value",
]
