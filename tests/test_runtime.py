"""pedrl.runtime's thread count: each job of a parallel sweep gets its share of the cores
(``hydra/launcher=parallel``)."""

import pytest
from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.hydra_config import HydraConfig

from pedrl.cli import CONFIG_DIR
from pedrl.runtime import available_cores, launcher_threads, share_of_cores


@pytest.mark.parametrize(
    ("n_jobs", "cores", "expected"),
    [(2, 2, 1), (1, 16, 16), (3, 16, 5), (32, 4, 1), (None, 4, 4), (-1, 8, 1), (-2, 8, 1), (-5, 16, 1), (-15, 16, 8)],
)
def test_share_of_cores_follows_joblib_counts(n_jobs, cores, expected):
    assert share_of_cores(n_jobs, cores) == expected


@pytest.mark.parametrize(("launcher", "n_jobs"), [("parallel", 2), ("parallel", 1), ("local", None)])
def test_a_parallel_job_gets_cores_over_n_jobs(launcher, n_jobs):
    overrides = [f"hydra/launcher={launcher}"] + ([f"hydra.launcher.n_jobs={n_jobs}"] if n_jobs else [])
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = hydra_compose(config_name="train", overrides=overrides, return_hydra_config=True)
    previous = HydraConfig.instance().cfg
    HydraConfig.instance().set_config(cfg)
    try:
        expected = max(1, available_cores() // n_jobs) if launcher == "parallel" else None
        assert launcher_threads() == expected
    finally:
        HydraConfig.instance().cfg = previous
