"""What every polygon of a scenario must be, and how messages show one: valid, non-empty, and within
:data:`MAX_COORDINATE` of the origin, where float32 positions keep millimetres."""

from __future__ import annotations

from typing import Any, Final

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from pedrl.common.checks import first_line

TOLERANCE: Final = 1e-6
"""Distance (m) within which an exit counts as lying on the boundary, and a spawn area inside the walkable area."""
MAX_COORDINATE: Final = 10_000.0
"""Largest ``|x|`` and ``|y|`` (m) of a scenario: float32 positions are 1 mm apart at 10 km from the origin (and 0.5 m
apart at UTM-like 5,400 km), so a room beyond it is refused rather than simulated with drifting positions."""
MISSING: Final = "???"
"""A mandatory config value left unset (OmegaConf's marker, kept as text by ``to_container``)."""


def check_extent(polygon: Polygon, what: str) -> None:
    """Refuse a polygon with a coordinate beyond :data:`MAX_COORDINATE`, where float32 positions would drift (or a
    coordinate that is not a finite number, :func:`check_finite`)."""
    check_finite(polygon, what)
    check_reach(float(np.abs(shapely.get_coordinates(polygon)).max(initial=0.0)), what)


def check_reach(farthest: float, what: str) -> None:
    """Refuse ``what`` reaching ``farthest`` (m, its largest ``|x|`` or ``|y|``) beyond :data:`MAX_COORDINATE`, in one
    line naming the distance and float32's spacing there."""
    if farthest > MAX_COORDINATE:
        raise ValueError(
            f"{what} is invalid: it reaches {farthest:.6g} m from the origin, {float32_spacing(farthest)}; every |x|"
            f" and |y| must be at most {MAX_COORDINATE:g} m"
            f" ({float(np.spacing(np.float32(MAX_COORDINATE))) * 1000:.1g} mm apart there): move it near (0, 0)"
        )


def float32_spacing(distance: float) -> str:
    """How far apart float32 positions are at ``distance`` (m) from the origin, for a message: beyond float32's
    range (3.4e38) there are none."""
    if distance >= float(np.finfo(np.float32).max):
        return f"beyond the range of float32 positions ({float(np.finfo(np.float32).max):.2g} m)"
    return f"where float32 positions are {float(np.spacing(np.float32(distance))):.2g} m apart"


def check_finite(shape: Any, what: str) -> None:
    """Refuse a geometry holding a coordinate that is not a finite number (NaN, or infinite: a number beyond
    1.8e308 in WKT), naming the first such vertex and where it is: its ring (the outer ring or a hole) and its
    place in it, counted from 1."""
    rings = (
        [("outer ring", shape.exterior), *((f"hole {index}", hole) for index, hole in enumerate(shape.interiors))]
        if isinstance(shape, Polygon) and not shape.is_empty
        else [("coordinates", shape)]
    )
    for name, ring in rings:
        coordinates = shapely.get_coordinates(ring)
        bad = np.flatnonzero(~np.isfinite(coordinates).all(-1))
        if bad.size:
            x, y = coordinates[bad[0]]
            raise ValueError(
                f"{what} is invalid: vertex {bad[0] + 1} of {len(coordinates)} of its {name}, ({x:g}, {y:g}), holds a"
                " coordinate that is not a finite number: every coordinate must be a finite number (m)"
            )


def check_polygon(polygon: Polygon, what: str) -> None:
    """Refuse anything but a valid, non-empty polygon of finite coordinates; ``what`` names it in the one-line
    message."""
    if not isinstance(polygon, Polygon) or polygon.is_empty:
        raise ValueError(
            f"{what} is invalid: must be a non-empty polygon, got {getattr(polygon, 'geom_type', polygon)}"
        )
    check_finite(polygon, what)  # before the validity test, which would blame a NaN on a self-intersection
    if not polygon.is_valid:
        reason = shapely.is_valid_reason(polygon)
        raise ValueError(f"{what} {bounds_text(polygon)} is invalid: {reason} (a polygon must not intersect itself)")


def short_reason(err: BaseException) -> str:
    """First line of an error, cut short: a parser may quote the text it read."""
    line = first_line(err)
    return line if len(line) <= 120 else line[:120] + "..."


def coords_text(line: LineString) -> str:
    """The vertices of ``line`` for a message: ``[(0, 1), (2, 1)]``."""
    return "[" + ", ".join(f"({x:g}, {y:g})" for x, y in line.coords) + "]"


def bounds_text(polygon: Any) -> str:
    """The bounding box of ``polygon`` for a message: ``[x_min, y_min] x [x_max, y_max]``."""
    x_min, y_min, x_max, y_max = polygon.bounds
    return f"[{x_min:g}, {y_min:g}] x [{x_max:g}, {y_max:g}]"
