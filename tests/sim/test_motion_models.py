"""A motion model is one object: a small frozen dataclass of its parameters, in the module of its kernels, checked
when it is made; the room takes one, a config names one by its name with its fields, and the flat keys that described
it before map onto the model that gives the same room."""

import dataclasses
import itertools

import pytest

from pedrl.configs.motion import check_no_flat_keys, flat_keys_of, flat_motion, old_keys_advice
from pedrl.scenarios import paper_room
from pedrl.sim.motion import (
    COLLISION_ORDERS,
    COLLISION_RULES,
    CONTACT_MODELS,
    MOTION_MODELS,
    Continuous,
    MotionModel,
    SlidingMotion,
    Steering,
    Stop,
    Yield,
    motion_from_config,
)

KERNEL_MODULES = {
    "stop": "pedrl.sim.motion.sequential",
    "simultaneous": "pedrl.sim.motion.simultaneous",
    "slide": "pedrl.sim.motion.sliding",
    "headway": "pedrl.sim.motion.sliding",
    "yield": "pedrl.sim.motion.sliding",
    "continuous": "pedrl.sim.motion.sliding",
}
BAD_VALUES = {"order": "last", "time_gap": 0.0, "contact": "slide", "time_step": 0.5, "steering": (8.0, 0.1)}
"""A value each field of a model refuses."""


@pytest.mark.parametrize("name", list(MOTION_MODELS))
def test_every_model_is_a_frozen_dataclass_in_the_module_of_its_kernels(name):
    model = MOTION_MODELS[name]
    assert dataclasses.is_dataclass(model) and model.__dataclass_params__.frozen
    assert issubclass(model, MotionModel) and model.name == name and model.__module__ == KERNEL_MODULES[name]
    with pytest.raises(dataclasses.FrozenInstanceError):
        model().order = "door_first"


@pytest.mark.parametrize(
    ("name", "key"), [(name, item.name) for name, model in MOTION_MODELS.items() for item in dataclasses.fields(model)]
)
def test_each_model_refuses_a_bad_parameter_in_one_line_naming_its_config_key(name, key):
    with pytest.raises(ValueError) as error:
        MOTION_MODELS[name](**{key: BAD_VALUES[key]})
    message = str(error.value)
    assert message.startswith(f"env.motion.{key}=") and "is invalid" in message and "\n" not in message


def old_flat_combinations():
    """Every combination of the flat keys (and two time gaps), with whether the room accepted it before the models:
    contact stop under either collision rule, every other contact under the sequential one; the continuous walking
    layer with headway or yield only."""
    for contact, rule, order, layer, gap in itertools.product(
        CONTACT_MODELS, COLLISION_RULES, COLLISION_ORDERS, ("step", "continuous"), (1.0, 0.4)
    ):
        valid = (contact == "stop" or rule == "sequential") and (layer == "step" or contact in ("headway", "yield"))
        flat = {"contact": contact, "collision_rule": rule, "collision_order": order, "motion": layer, "time_gap": gap}
        yield flat, valid


@pytest.mark.parametrize(("flat", "valid"), list(old_flat_combinations()))
def test_the_models_cover_every_valid_flat_combination_and_no_invalid_one(flat, valid):
    """A valid combination maps onto a model that reads what the room read of it (the contact rule, the collision
    rule, the order where the sequential rule draws one, the time gap where a headway rule reads it, the walking
    layer); an invalid one is refused in one line."""
    if not valid:
        with pytest.raises(ValueError, match=r"^[^\n]*is invalid"):
            flat_motion(flat)
        return
    model = flat_motion(flat)
    sequential = flat["collision_rule"] == "sequential"
    headway = flat["contact"] in ("headway", "yield")
    assert (model.contact, model.rule) == (flat["contact"], flat["collision_rule"])
    assert model.order == (flat["collision_order"] if sequential else "random")
    assert model.time_gap == (flat["time_gap"] if headway else None)
    assert (model.steering is not None) == (flat["motion"] == "continuous")


def model_variants():
    """Every model with every value of its choices (order, the continuous layer's contact)."""
    for model in MOTION_MODELS.values():
        names = [item.name for item in dataclasses.fields(model) if item.name in ("order", "contact")]
        choices = {"order": COLLISION_ORDERS, "contact": ("headway", "yield")}
        for values in itertools.product(*(choices[name] for name in names)):
            yield model(**dict(zip(names, values, strict=True)))


@pytest.mark.parametrize("model", list(model_variants()), ids=repr)
def test_every_model_is_a_combination_the_room_accepted_and_maps_back_from_it(model):
    """No model describes a room the flat keys could not: each reads back from its flat keys as itself."""
    flat = {
        "contact": model.contact,
        "collision_rule": model.rule,
        "collision_order": model.order,
        "motion": "step" if model.steering is None else "continuous",
        "time_gap": 1.0 if model.time_gap is None else model.time_gap,
    }
    assert flat_motion(flat) == model
    assert motion_from_config(model.to_config()) == model


def test_a_room_takes_one_model_and_moves_by_it():
    room = paper_room(width=10.0, length=12.0).room(num_agents=3, motion=Yield(time_gap=0.4, order="door_first"))
    constants = room.motion_constants
    assert room.params.motion == room.motion == Yield(0.4, "door_first")
    assert isinstance(constants, SlidingMotion) and constants.time_gap == 0.4 and constants.yield_to_earlier
    assert constants.steering is None
    walking = paper_room().room(num_agents=3, motion=Continuous(steering=Steering(wall_strength=2.0)))
    assert walking.motion_constants.steering == Steering(wall_strength=2.0) and walking.num_substeps == 20


def test_the_old_keys_are_told_the_model_they_mean():
    advice = old_keys_advice({"contact": "yield", "collision_order": "door_first", "time_gap": 0.4})
    assert "motion=yield env.motion.time_gap=0.4 env.motion.order=door_first" in advice
    assert "Yield(time_gap=0.4, order='door_first') in Python" in advice and "\n" not in advice
    assert "motion=stop" in old_keys_advice({"collision_order": "random"}) and Stop() == flat_motion({})


@pytest.mark.parametrize("name", list(MOTION_MODELS))
def test_the_old_keys_change_the_model_the_config_chooses(name):
    """On a run that chooses a model (``motion=continuous``), an old key means that model's field: the walking layer's
    ``env.motion.time_gap=0.4``, not the step model the flat keys' defaults give (the control: no model chosen)."""
    model = MOTION_MODELS[name]()
    assert flat_motion(flat_keys_of(model)) == model  # the inverse, the base of the advice
    advice = old_keys_advice({"time_gap": 0.4}, base=model)
    if "time_gap" in {item.name for item in dataclasses.fields(model)}:
        assert f"motion={name} env.motion.time_gap=0.4 on the command line" in advice
    else:
        assert f"motion={name} on the command line" in advice
    assert "motion=stop on the command line" in old_keys_advice({"time_gap": 0.4})  # no model chosen: the flat ones
    walking = Continuous(contact="yield", time_gap=0.4, steering=Steering(wall_strength=2.0))
    assert flat_motion(flat_keys_of(walking)) == walking


def test_a_config_holding_a_model_and_an_old_key_is_told_that_models_key():
    env = {"motion": {"name": "continuous", "contact": "yield"}, "time_gap": 0.4}
    with pytest.raises(ValueError, match=r"motion=continuous env\.motion\.contact=yield env\.motion\.time_gap=0\.4 on"):
        check_no_flat_keys(env)
