"""Re-export a checkpoint written before rooms were stored with its room's WKT text (``python -m pedrl.embed``)."""

from __future__ import annotations

import copy
import os
from pathlib import Path

from pedrl.configs.stored import check_config_bounds, check_stored_config
from pedrl.io import Checkpoint, CheckpointError, load_checkpoint, save_checkpoint
from pedrl.scenarios import build_scenario, geometry_file, inline_geometry


def embed_geometry(path: str | os.PathLike, wkt: str | os.PathLike, *, output: str | os.PathLike | None = None) -> Path:
    """Re-export a checkpoint that names its room's WKT file (``scenario.geometry``, written before rooms were
    stored) with that room's WKT text in its stored config; ``python -m pedrl.embed`` runs it.

    ``wkt`` is read once, under the bounds of :func:`pedrl.scenarios.read_wkt`, and the stored exits and spawn areas
    must fit its polygon. Tensors and every other value are kept; the file is written atomically, to ``output``
    (default: in place).

    Raises:
        CheckpointError: one line, for a checkpoint that names no WKT file, a bad WKT file, or a room its stored
            exits do not fit.
    """
    source = load_checkpoint(path)
    where = f"checkpoint {str(source.path)!r}"
    config = copy.deepcopy(check_config_bounds(source.metadata.get("config"), where))  # bounded before any walk
    scenario = config.get("scenario") if isinstance(config, dict) else None
    if geometry_file(scenario) is None:
        raise CheckpointError(f"{where} names no WKT file (scenario.geometry): there is nothing to re-export")
    try:
        scenario = inline_geometry({**scenario, "geometry": str(wkt)})
        build_scenario(scenario, files=False)  # the stored exits and spawn areas must fit the polygon
    except ValueError as err:
        raise CheckpointError(f"cannot re-export {where}: {err}") from None
    config["scenario"] = scenario
    header = ("format", "format_version", "pedrl_version")  # written anew by save_checkpoint
    metadata = {key: value for key, value in source.metadata.items() if key not in header} | {"config": config}
    destination = Path(output) if output is not None else source.path
    check_stored_config(Checkpoint(tensors=source.tensors, metadata=metadata, path=source.path))  # its content
    return save_checkpoint(destination, tensors=source.tensors, metadata=metadata)
