"""The constants of a batch of rooms, :class:`RoomParams`: every setting of :class:`pedrl.sim.RoomEnv` but the batch
shape, the device and the walkable area, validated, with what the fast path (the fused numba trial) supports of each.

Each field declares its fast-path support with :func:`setting`: every value (:data:`ANY`), or only some
(:func:`only`). :meth:`RoomParams.fast_path_reason` is an allow-list computed from those declarations, so a new
setting cannot be silently ignored by the fast path: ``tests/sim/test_params.py`` fails for a constructor argument of
``RoomEnv`` that has no field here, or a field without a declaration.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Final

from pedrl.sim.motion import Continuous, Headway, MotionModel, Slide, Stop, Yield

__all__ = ["ANY", "FastSupport", "RoomParams", "only", "setting", "undeclared"]

FAST: Final = "fast"
"""The metadata key of a field's :class:`FastSupport`."""


@dataclass(frozen=True)
class FastSupport:
    """The values of a setting that the fast path runs: all (``values`` None) or those listed (a class listed stands
    for its instances: a motion model's class, whatever its parameters)."""

    values: tuple[Any, ...] | None = None

    def reason(self, name: str, value: Any) -> str | None:
        """Why the fast path cannot run with ``name=value`` (one phrase), or None when it can."""
        if self.values is None or value in self.values:
            return None
        if any(isinstance(allowed, type) and type(value) is allowed for allowed in self.values):
            return None
        shown = [_shown(v) for v in self.values]
        allowed = shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} or {shown[-1]}"
        return f"with {name}={_shown(value)} (it runs {name}={allowed})"


ANY: Final = FastSupport()
"""Every value runs on the fast path."""


def only(*values: Any) -> FastSupport:
    """Only ``values`` run on the fast path."""
    return FastSupport(tuple(values))


def setting(support: FastSupport) -> Any:
    """A :class:`RoomParams` field with its fast-path ``support`` declared."""
    return field(metadata={FAST: support})


def _shown(value: Any) -> str:
    """A value as the config writes it: ``true``, a motion model (or its class) by its name."""
    if isinstance(value, bool):
        return str(value).lower()
    return value.name if isinstance(value, MotionModel | type) else str(value)


@dataclass(frozen=True)
class RoomParams:
    """The validated settings of a room (``RoomEnv(...)``'s arguments of the same names; units and meanings there)."""

    agent_radius: float = setting(ANY)
    max_speed: float = setting(ANY)
    decisions_per_second: float = setting(ANY)
    max_decisions: int = setting(ANY)
    num_neighbours: int = setting(ANY)
    num_walls: int = setting(ANY)
    speed_ratios: tuple[float, ...] = setting(ANY)
    turn_ratios: tuple[float, ...] = setting(ANY)
    reward_goal: float = setting(ANY)
    reward_crash_wall: float = setting(ANY)
    reward_crash_agent: float = setting(ANY)
    reward_default: float = setting(ANY)
    substep_length: float = setting(ANY)
    goal_depth: float = setting(ANY)
    reward_progress: float = setting(ANY)
    compile_sensing: bool = setting(only(False))  # the fast path senses in its own kernel
    action_frame: str = setting(ANY)
    # every model but Simultaneous; Stop with walls that are not all axis-aligned: RoomEnv.fast_path_reason
    motion: MotionModel = setting(only(Stop, Slide, Headway, Yield, Continuous))
    queue_weight: float = setting(ANY)  # used at placement, in torch

    @classmethod
    def of(cls, room: Any) -> RoomParams:
        """The settings of a built room (a ``RoomEnv``): each field its attribute of the same name, the rewards from
        its reward table."""
        rewards = room.rewards
        special = {
            "reward_goal": rewards.goal,
            "reward_crash_wall": rewards.crash_wall,
            "reward_crash_agent": rewards.crash_agent,
            "reward_default": rewards.default,
        }
        values = {f.name: special[f.name] if f.name in special else getattr(room, f.name) for f in fields(cls)}
        return cls(**{name: tuple(v) if isinstance(v, list) else v for name, v in values.items()})

    def fast_path_reason(self) -> str | None:
        """Why the fast path cannot run these settings (one phrase, the first setting it does not support), or None."""
        for item in fields(self):
            reason = item.metadata[FAST].reason(item.name, getattr(self, item.name))
            if reason is not None:
                return reason
        return None


def undeclared(cls: type) -> list[str]:
    """The fields of the dataclass ``cls`` that declare no fast-path support."""
    return [item.name for item in fields(cls) if not isinstance(item.metadata.get(FAST), FastSupport)]
