"""RoomParams: every setting of RoomEnv has a field, every field declares what the fast path supports, and the fast
path's eligibility is the allow-list computed from those declarations."""

import dataclasses
import inspect

import pytest

from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.motion import Continuous, Headway, Simultaneous, Yield
from pedrl.sim.params import ANY, RoomParams, only, setting, undeclared

BATCH_ARGUMENTS = {"self", "num_replicas", "num_agents", "device", "area"}
"""RoomEnv's arguments that are not settings of the room: the batch shape, the device and the walkable area."""


def test_every_setting_of_the_room_has_a_field():
    settings = set(inspect.signature(RoomEnv.__init__).parameters) - BATCH_ARGUMENTS
    assert settings == {field.name for field in dataclasses.fields(RoomParams)}


def test_every_field_declares_its_fast_path_support():
    assert undeclared(RoomParams) == []


def test_a_field_without_a_declaration_is_found():
    """The control: a planted setting with no declaration."""

    @dataclasses.dataclass(frozen=True)
    class Planted:
        max_speed: float = setting(ANY)
        new_option: bool = False

    assert undeclared(Planted) == ["new_option"]


def test_the_params_are_the_validated_arguments():
    env = paper_room(width=10.0, length=12.0).room(
        num_agents=3, motion=Yield(), speed_ratios=[0, 0, 0, 0, 0, 0.1, 0.2, 0.5, 1]
    )
    assert env.params.motion == Yield()
    assert env.params.speed_ratios == (0, 0, 0, 0, 0, 0.1, 0.2, 0.5, 1)
    assert env.params.substep_length == env.agent_radius  # None means the body radius
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
