"""Interrupt a training run mid-phase, resume it, and compare it with an uninterrupted one."""

import pytest
import torch

from pedrl.algos.records import RunRecord
from pedrl.io import load_checkpoint, read_csv
from pedrl.train import train


def assert_resume_equals_uninterrupted(
    train_config, overrides, tmp_path, monkeypatch, *, stop_after: int, tensors: str = "q_values"
) -> None:
    """Train ``overrides`` whole into ``tmp_path/full``; train them into ``tmp_path/cut`` until a KeyboardInterrupt
    after ``stop_after`` logged trials, then resume it (``resume=true``): the tables (``tensors="all"``: every tensor
    of the last checkpoint) and the learning curve (bar its clock column) must be the same."""
    train(train_config(*overrides), run_dir=tmp_path / "full")
    original = RunRecord.log_trial
    calls = {"n": 0}

    def interrupt(self, *args, **kwargs):
        original(self, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == stop_after:
            raise KeyboardInterrupt

    monkeypatch.setattr(RunRecord, "log_trial", interrupt)
    with pytest.raises(KeyboardInterrupt):
        train(train_config(*overrides), run_dir=tmp_path / "cut")
    monkeypatch.setattr(RunRecord, "log_trial", original)
    train(train_config(*overrides, "resume=true"), run_dir=tmp_path / "cut")
    full, cut = (load_checkpoint(tmp_path / run / "checkpoints" / "last.safetensors") for run in ("full", "cut"))
    names = list(full.tensors) if tensors == "all" else [tensors]
    assert full.tensors.keys() == cut.tensors.keys()
    for name in names:
        assert torch.equal(full.tensors[name], cut.tensors[name]), name
    strip = lambda rows: [{k: v for k, v in r.items() if k != "decisions_per_s"} for r in rows]  # noqa: E731
    assert strip(read_csv(tmp_path / "full" / "learning_curve.csv")) == strip(
        read_csv(tmp_path / "cut" / "learning_curve.csv")
    )
