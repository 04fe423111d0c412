"""RoomParams: every setting of RoomEnv has a field, every field declares what the fast path supports and how the
kernels receive it, the fast path's eligibility is the allow-list computed from those declarations, and the kernels'
room constants are packed from them."""

import dataclasses
import importlib
import inspect
import pkgutil
from dataclasses import replace

import numpy as np
import pytest

from pedrl._numba import numba_available
from pedrl.scenarios import paper_room
from pedrl.sim import DEFAULT_SPEED_RATIOS, RoomEnv
from pedrl.sim.motion import CONTACT_MODELS, Continuous, Headway, Simultaneous, Slide, Yield
from pedrl.sim.params import (
    ANY,
    KernelRoom,
    RoomParams,
    _kernel_entries,
    host,
    kernel,
    model,
    only,
    setting,
    through,
    undeclared,
    unread,
)

MAX_ARGUMENTS = 8
"""Most arguments of a hand-written constructor (self aside): more, and a reader cannot follow a call."""


def constructor_arguments(cls: type) -> list[str]:
    """The arguments of ``cls.__init__`` but ``self``."""
    return [name for name in inspect.signature(cls.__init__).parameters if name != "self"]


def hand_written_classes(package) -> list[type]:
    """The classes defined in ``package``'s modules with a constructor of their own that no dataclass or named
    tuple generated (those are value objects: one field per argument)."""
    found = []
    for info in pkgutil.walk_packages(package.__path__, f"{package.__name__}."):
        if info.name.endswith("_kernel"):
            continue  # numba kernels: no classes, a slow import
        module = importlib.import_module(info.name)
        for cls in vars(module).values():
            if not isinstance(cls, type) or cls.__module__ != module.__name__ or "__init__" not in vars(cls):
                continue
            if dataclasses.is_dataclass(cls) or issubclass(cls, tuple):
                continue
            found.append(cls)
    return found


def test_the_room_takes_its_area_its_settings_and_the_batch():
    """RoomEnv(area, params, num_replicas, num_agents, device): every setting of the room is a field of RoomParams."""
    assert constructor_arguments(RoomEnv) == ["area", "params", "num_replicas", "num_agents", "device"]
    assert isinstance(paper_room().room(num_agents=2).params, RoomParams)


def test_no_constructor_of_the_simulation_takes_more_than_eight_arguments():
    """The control: a planted class of nine arguments is found."""
    import pedrl.sim

    classes = hand_written_classes(pedrl.sim)
    assert RoomEnv in classes
    crowded = {cls.__qualname__: len(constructor_arguments(cls)) for cls in classes}
    assert {name: count for name, count in crowded.items() if count > MAX_ARGUMENTS} == {}

    class Planted:
        def __init__(self, a, b, c, d, e, f, g, h, i):
            pass

    assert len(constructor_arguments(Planted)) > MAX_ARGUMENTS


def test_settings_by_name_are_the_settings_and_a_wrong_name_is_refused_in_one_line():
    params = RoomParams.from_settings({"max_speed": 1.34}, motion=Yield(order="door_first"))
    assert params == RoomParams(max_speed=1.34, motion=Yield(order="door_first"))
    assert params.agent_radius == 0.4 and params.speed_ratios == DEFAULT_SPEED_RATIOS  # the rest: the defaults
    with pytest.raises(ValueError, match=r"^contact is not a setting of the room: its settings are agent_radius, "):
        RoomParams.from_settings(contact="yield")
    with pytest.raises(ValueError, match=r"^max_speed=-1.0 is invalid"):
        replace(params, max_speed=-1.0)  # checked when made, a changed copy too


def test_every_field_declares_its_fast_path_support():
    assert undeclared(RoomParams) == []


def test_a_field_without_a_declaration_is_found():
    """The control: a planted setting with no declaration."""

    @dataclasses.dataclass(frozen=True)
    class Planted:
        max_speed: float = setting(ANY, host("the area"))
        new_option: bool = False

    assert undeclared(Planted) == ["new_option"]


def test_a_setting_cannot_be_declared_without_saying_how_the_kernels_receive_it():
    with pytest.raises(TypeError):
        setting(ANY)  # the missing packing is the point


def test_a_new_packed_setting_reaches_the_kernels_by_its_name():
    """The kernels' constants are built from the declarations: a new field with a packing is a new entry, a field
    that takes part in another's names it, and a name that no entry has is refused when the class is read."""

    @dataclasses.dataclass(frozen=True)
    class Planted:
        width: float = setting(ANY, host("the area"))
        speed: float = setting(ANY, kernel(np.float32))
        order: str = setting(ANY, kernel(lambda order: order == "first", "first"))
        gap: float = setting(ANY, through("first"))

    assert _kernel_entries(Planted) == ["speed", "first"]

    @dataclasses.dataclass(frozen=True)
    class Dangling:
        gap: float = setting(ANY, through("nowhere"))

    with pytest.raises(TypeError, match="nowhere"):
        _kernel_entries(Dangling)


def test_the_kernels_read_every_packed_setting_of_the_room():
    env = paper_room(width=10.0, length=12.0).room(num_agents=3, motion=Yield(time_gap=0.7, order="door_first"))
    room = env.params.kernel_room(env)
    assert isinstance(room, KernelRoom) and room._fields == tuple(_kernel_entries(RoomParams))
    assert room.max_speed == np.float32(env.params.max_speed) and room.agent_radius == env.params.agent_radius
    assert room.door_first and room.time_gap == 0.7 and room.num_substeps == env.num_substeps
    assert room.contact == CONTACT_MODELS.index("yield") and not room.continuous
    assert (
        room.reward_goal == np.float32(env.params.rewards.goal) and room.decision_length == env.params.decision_length
    )
    assert np.array_equal(room.speed_changes, env.speed_changes.numpy())
    hosted = {field.name for field in dataclasses.fields(RoomParams) if field.metadata["packing"].host is not None}
    area = {"goal_depth"}  # the kernels read the area as walls and exits
    assert hosted == area | {"compile_sensing", "queue_weight"}


def test_a_field_of_a_motion_model_the_kernels_do_not_read_is_found():
    """A model the fast path runs with a field its packing's ``reads`` does not list: a TypeError when the class is
    read, so that a new parameter of a model cannot be left out of the kernels' constants; the control: the room's
    own declarations read every field of every model it runs."""

    @dataclasses.dataclass(frozen=True)
    class Anticipating(Yield):
        anticipation: float = 0.5

    @dataclasses.dataclass(frozen=True)
    class Planted:
        motion: Yield = setting(only(Yield, Anticipating), model(reads=("time_gap", "order"), gap=lambda m: m.time_gap))

    assert unread(Planted) == ["motion.Anticipating.anticipation"]
    with pytest.raises(TypeError, match="Anticipating.anticipation"):
        _kernel_entries(Planted)
    assert unread(RoomParams) == []


def test_the_params_are_the_validated_arguments():
    env = paper_room(width=10.0, length=12.0).room(
        num_agents=3, motion=Yield(), speed_ratios=[0, 0, 0, 0, 0, 0.1, 0.2, 0.5, 1]
    )
    assert env.params.motion == Yield()
    assert env.params.speed_ratios == (0, 0, 0, 0, 0, 0.1, 0.2, 0.5, 1)
    assert env.params.substep_length is None and env.params.substep == env.params.agent_radius  # None: the body radius
    with pytest.raises(dataclasses.FrozenInstanceError):
        env.params.max_speed = 5.0


@pytest.mark.parametrize(
    ("settings", "reason"),
    [
        ({}, None),
        ({"motion": Headway(time_gap=0.5, order="door_first")}, None),
        ({"motion": Continuous(contact="yield")}, None),
        (
            {"motion": Simultaneous()},
            "with motion=simultaneous (it runs motion=stop, slide, headway, yield or continuous)",
        ),
        ({"compile_sensing": True}, "with compile_sensing=true (it runs compile_sensing=false)"),
    ],
)
def test_the_fast_path_runs_what_the_declarations_allow(settings, reason):
    env = paper_room(width=10.0, length=12.0).room(num_agents=3, **settings)
    assert env.fast_path_reason() == reason


def test_only_lists_the_allowed_values():
    assert only("a", "b").reason("x", "c") == "with x=c (it runs x=a or b)"
    assert only("a").reason("x", "a") is None and ANY.reason("x", object()) is None
    # a class stands for its instances, whatever their parameters, and for no subclass's
    assert only(Headway).reason("motion", Headway(time_gap=0.3)) is None
    assert only(Headway).reason("motion", Yield()) == "with motion=yield (it runs motion=headway)"


@pytest.mark.skipif(not numba_available(), reason="numba")
@pytest.mark.parametrize(
    "motion", [Slide(), Headway(time_gap=0.7), Yield(order="door_first"), Continuous(contact="yield")]
)
def test_a_sliding_model_s_kernel_constants_are_one_record_from_either_side(motion):
    """The fused step builds the sliding kernel's constants from the room's kernel constants, the torch room's
    dispatcher from its decision's arguments: one record, equal field by field."""
    from pedrl.sim.motion.sliding_kernel import constants_of, sliding_constants

    env = paper_room(width=10.0, length=12.0).room(num_agents=3, motion=motion)
    decision = env.motion_constants
    expected = constants_of(
        agent_radius=decision.agent_radius,
        substep_length=decision.decision_length / decision.num_substeps,
        num_substeps=decision.num_substeps,
        time_gap=decision.time_gap,
        yield_to_earlier=decision.yield_to_earlier,
        steering=decision.steering,
    )
    assert sliding_constants(env.params.kernel_room(env)) == expected
