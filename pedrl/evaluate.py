"""``pedrl-eval``: reload a checkpoint and simulate it with more agents (paper section 6, Tables 4 and 5).

``main`` is a thin ``@hydra.main`` wrapper around :func:`pedrl.evaluation.evaluate` (``evaluate(cfg, run_dir=...)``,
in Hydra's output dir), whose package docstring describes the evaluation and lists its outputs.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from pedrl.cli import CONFIG_DIR, checked_groups, hydra_output_dir, run_reporting_errors
from pedrl.evaluation import controllers, evaluate, print_table
from pedrl.evaluation.config import source


@checked_groups("pedrl-eval", CONFIG_DIR, groups=("scenario",))
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="eval")
def main(cfg: DictConfig) -> None:
    """Evaluate a checkpoint at scale and print Tables 4/5; a bad value or file exits with code 2 and one line."""
    rows = run_reporting_errors("pedrl-eval", lambda: evaluate(cfg, run_dir=hydra_output_dir()))
    print_table(rows, f"{' and '.join(controllers(cfg))} on the same scenes, epsilon={cfg.epsilon}, {source(cfg)[1]}")


if __name__ == "__main__":
    main()
