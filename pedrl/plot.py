"""``pedrl-plot``: learning curves of one or more runs together, in the style of the paper's Figures 4 to 7.

``pedrl-plot runs=[outputs/A,outputs/B,outputs/C]`` reads each run's ``learning_curve.csv`` and draws the success
rate (mean over learning processes, with a ±std band) against the trial number, with the iteration or stage
boundaries of every run dashed (Figures 5 and 7); ``layout=phases`` draws every phase from its own start instead
(Figures 4 and 6). ``main`` is a thin Hydra wrapper around :func:`pedrl.learning_curves.plot_runs`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig, ListConfig, OmegaConf

from pedrl.cli import CONFIG_DIR, checked_groups, run_reporting_errors
from pedrl.learning_curves import plot_runs


@checked_groups("pedrl-plot", CONFIG_DIR, groups=())
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="plot")
def main(cfg: DictConfig) -> None:
    """Plot the runs of ``cfg.runs`` together."""

    def plot() -> Path:
        marks = cfg.get("marks")  # checked in plot_runs: marks=5 is a number, not a list
        if isinstance(marks, ListConfig | DictConfig):
            marks = OmegaConf.to_container(marks, resolve=True)
        return plot_runs(
            _as_list(cfg.runs),
            cfg.output,
            labels=_as_list(cfg.labels),
            metric=cfg.metric,
            smooth=cfg.smooth,
            marks=marks,
            layout=cfg.layout,
        )

    path = run_reporting_errors("pedrl-plot", plot)
    print(f"wrote {path}")


def _as_list(value: Any) -> list[Any] | None:
    """A command-line value as a list: ``runs=outputs/a`` means one run, not a list of characters."""
    if value is None or isinstance(value, str | Path):
        return None if value is None else [value]
    return list(value)


if __name__ == "__main__":
    main()
