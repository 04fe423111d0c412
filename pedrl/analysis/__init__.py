"""Pedestrian-dynamics analysis of recorded trajectories (paper section 6).

PedPy export, Gaussian local density, speed and flow, fundamental diagrams, density maps, and figures. Recorded crowds
are one type, :class:`Recording` (defined on the floor of the layering, :mod:`pedrl.common.recording`, so that the
trial can record it); one run of it in its area, :meth:`Trajectories.of_run`, is what the measures read.

Depends only on numpy and matplotlib; it never imports :mod:`pedrl.sim` or torch. PedPy (the optional extra
``pedrl[analysis]``) reads the exported files but is not needed here.
"""

from pedrl.analysis.density_map import DensityMap, compute_density_map, compute_tile_edges, load_density_map
from pedrl.analysis.fundamental import (
    DEFAULT_MIN_DENSITY,
    DEFAULT_RADIUS,
    DENSITY_COL,
    FLOW_COL,
    FRAME_COL,
    SPEED_COL,
    TRIAL_COL,
    FundamentalDiagram,
    SpeedDensityFit,
    SpeedDensityModel,
    compute_flow,
    compute_fundamental_diagram,
    compute_gaussian_density,
    compute_gaussian_weights,
    compute_local_speed,
    compute_local_velocity,
    default_measurement_point,
    fit_speed_density,
)
from pedrl.analysis.plots import (
    animate_trial,
    plot_density_map,
    plot_fundamental_diagram,
    plot_learning_curves,
    plot_room,
)
from pedrl.analysis.trajectories import DEFAULT_EXIT_DEPTH, AreaGeometry, Geometry, RoomGeometry, Trajectories
from pedrl.analysis.trajectory_files import (
    FRAMES_PAST_EXIT,
    ID_COL,
    X_COL,
    Y_COL,
    read_pedpy_trajectory,
    trajectories_for_export,
    write_geometry_wkt,
    write_jupedsim_sqlite,
    write_pedpy_trajectories,
    write_pedpy_trajectory,
)
from pedrl.common.recording import Recording

__all__ = [
    "DEFAULT_EXIT_DEPTH",
    "DEFAULT_MIN_DENSITY",
    "DEFAULT_RADIUS",
    "DENSITY_COL",
    "FLOW_COL",
    "FRAME_COL",
    "FRAMES_PAST_EXIT",
    "ID_COL",
    "SPEED_COL",
    "TRIAL_COL",
    "X_COL",
    "Y_COL",
    "DensityMap",
    "FundamentalDiagram",
    "AreaGeometry",
    "Geometry",
    "Recording",
    "RoomGeometry",
    "SpeedDensityFit",
    "SpeedDensityModel",
    "Trajectories",
    "animate_trial",
    "compute_density_map",
    "compute_flow",
    "compute_fundamental_diagram",
    "compute_gaussian_density",
    "compute_gaussian_weights",
    "compute_local_speed",
    "compute_local_velocity",
    "compute_tile_edges",
    "default_measurement_point",
    "fit_speed_density",
    "load_density_map",
    "plot_density_map",
    "plot_fundamental_diagram",
    "plot_learning_curves",
    "plot_room",
    "read_pedpy_trajectory",
    "trajectories_for_export",
    "write_geometry_wkt",
    "write_jupedsim_sqlite",
    "write_pedpy_trajectories",
    "write_pedpy_trajectory",
]
