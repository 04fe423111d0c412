"""What a training run does when it goes wrong or is watched from a log file: it stops with one line when learning
turns inf or NaN, and prints one line per phase instead of a progress bar when stderr is not a terminal."""

import pytest
from omegaconf import open_dict

import pedrl.sim.env
from pedrl.train import train


def test_a_run_whose_tables_turn_non_finite_stops_with_one_line(train_config, tmp_path, monkeypatch):
    """Rewards near float32's limit (here let through by lifting the bound) overflow the returns to inf."""
    monkeypatch.setattr(pedrl.sim.env, "MAX_REWARD", float("inf"))
    cfg = train_config("algo=vqql", "logger=none", "env.reward_goal=3e38", "env.reward_crash_wall=-3e38")
    with pytest.raises(ValueError, match=r"phase 1, trial \d+: the returns or Q tables turned inf or NaN") as error:
        train(cfg, run_dir=tmp_path)
    assert "\n" not in str(error.value)
    assert not (tmp_path / "checkpoints").exists()  # no inf table was saved
    curve = (tmp_path / "learning_curve.csv").read_text().lower()
    assert "inf" not in curve and "nan" not in curve  # no non-finite row was written


def test_without_a_terminal_the_progress_bar_is_one_line_per_phase(train_config, tmp_path, capsys):
    cfg = train_config("algo=it_vqql", "logger=none")
    with open_dict(cfg):
        cfg.progress = True
    train(cfg, run_dir=tmp_path)
    captured = capsys.readouterr()
    assert "\r" not in captured.err and "it/s" not in captured.err  # no bar frames in a log file
    phase_lines = [line for line in captured.out.splitlines() if line.startswith("it_vqql phase")]
    assert len(phase_lines) == 2, captured.out
    assert phase_lines[0].startswith("it_vqql phase 1/2 (20 agents): 10 trials in ")
    assert ", success " in phase_lines[1]
