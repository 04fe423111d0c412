"""One walkable area: the scenario describes it, the simulation reads it compiled, routes have one type.

``pedrl.sim`` may not import shapely nor ``pedrl.scenarios`` (tests/test_layout.py), so the tensors a room reads
(:class:`pedrl.sim.Geometry`) are compiled from a :class:`pedrl.scenarios.Scenario`, never written by hand in the
simulation (docs/design.md, "One walkable area"). Read from the source with ``ast`` where the rule is about code.
"""

import ast
import inspect
from pathlib import Path

import pytest
import torch

from pedrl.configs import env_factory
from pedrl.scenarios import build_scenario, custom, paper_room
from pedrl.sim import Geometry, RoomEnv
from pedrl.sim.geometry import RouteTable

PACKAGE = Path(__file__).resolve().parents[2] / "pedrl"


def calls_of(path: Path, owner: str) -> list[str]:
    """``owner.method`` for every call of a method of ``owner`` (``Geometry``) in the file at ``path``."""
    calls = []
    for node in ast.walk(ast.parse(path.read_text())):
        function = node.func if isinstance(node, ast.Call) else None
        if isinstance(function, ast.Attribute) and isinstance(function.value, ast.Name) and function.value.id == owner:
            calls.append(f"{owner}.{function.attr}")
    return calls


def test_a_room_has_no_default_area():
    """RoomEnv builds no area of its own: no second path beside the scenario's."""
    area = inspect.signature(RoomEnv.__init__).parameters["area"]
    assert area.default is inspect.Parameter.empty
    assert not hasattr(Geometry, "rectangle")


def test_only_the_scenario_compiles_an_area():
    """No module of the package but the scenario's model builds a Geometry (the paper's room included)."""
    builders = {
        str(path.relative_to(PACKAGE.parent)): calls
        for path in sorted(PACKAGE.rglob("*.py"))
        if (calls := [call for call in calls_of(path, "Geometry") if call != "Geometry.to"])
    }
    assert builders == {"pedrl/scenarios/model.py": ["Geometry.build"]}


def test_routes_have_one_type():
    """The scenario's routes are the simulation's RouteTable, and the compiled area holds that very table (the
    kernels' named tuples, such as the agents' waypoints as ``spawning.Routes``, are views, not route types)."""
    classes = [
        f"{path.name}:{node.name}"
        for path in sorted(PACKAGE.rglob("*.py"))
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.ClassDef)
        and "Route" in node.name
        and "NamedTuple" not in [ast.unparse(base) for base in node.bases]
    ]
    assert classes == ["geometry.py:RouteTable"]
    wkt = "POLYGON ((0 0, 20 0, 20 8, 10 8, 10 20, 0 20, 0 0))"  # an L: the exit is out of sight from the far leg
    scenario = custom(geometry=wkt, exits=[[10, 20, 0, 20]])
    assert isinstance(scenario.routes, RouteTable) and scenario.geometry().routes == scenario.routes


def test_the_paper_room_is_a_scenario_like_any_other():
    """The env config with no scenario builds the paper's room through its scenario, as every room is built."""
    env = {"_target_": "pedrl.sim.RoomEnv", "width": 10.0, "length": 12.0, "door_width": 3.0}
    room = env_factory(env)(num_replicas=1, num_agents=4)
    compiled = build_scenario(None, room=env).geometry()
    assert room.geometry.name == "paper_room" and torch.equal(room.geometry.walls, compiled.walls)
    assert room.geometry.bounds == (0.0, 0.0, 10.0, 12.0)


def test_a_room_refuses_anything_but_a_compiled_area():
    with pytest.raises(ValueError, match=r"^area of type PaperRoom is invalid: must be a pedrl.sim.Geometry"):
        RoomEnv(paper_room())
