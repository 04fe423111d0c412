"""What a training run does when it goes wrong or is watched from a log file: it stops with one line when learning
turns inf or NaN, refuses before compute a K that gathering cannot reach and shrinks K with one line when the states
hold fewer distinct ones, and prints one line per phase instead of a progress bar when stderr is not a terminal."""

import warnings

import pytest
from omegaconf import open_dict

import pedrl.sim.rewards
from pedrl.io import load_checkpoint
from pedrl.notices import PedrlWarning, warn
from pedrl.train import train


def test_a_run_whose_tables_turn_non_finite_stops_with_one_line(train_config, tmp_path, monkeypatch):
    """Rewards near float32's limit (here let through by lifting the bound) overflow the returns to inf."""
    monkeypatch.setattr(pedrl.sim.rewards, "MAX_REWARD", float("inf"))
    cfg = train_config("algo=vqql", "logger=none", "env.reward_goal=3e38")
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


# ---------------------------------------------------------------------- K against the gathered states (issue 20)
@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            ("vq.num_prototypes=4096",),
            "vq.num_prototypes=4096 is invalid: phase 1 gathers at most 1200 states per process (algo.gather_trials=2 "
            "x rooms_per_process=1 x 20 agents x env.max_decisions=30) and k-means needs one per prototype: must be "
            "at most 1200, or raise algo.gather_trials",
        ),
        (
            ("vq.num_prototypes=4096", "vq.per_process=false"),
            "at most 2400 states for the shared quantizer (processes=2",
        ),
        (
            ("algo=in_vqql", "vq.num_prototypes=61"),
            "phase 1 gathers at most 60 states per process (algo.gather_trials=2",
        ),
        (  # the mix rooms are gathered too: 2 x (20 + 6) agents x 30 decisions per process
            ("algo=vqql", "vq.num_prototypes=1561", "+mix=[{name: corridor, length: 40.0, width: 2.0, agents: 6}]"),
            "at most 1560 states per process (algo.gather_trials=2 x rooms_per_process=1 x 26 agents (20 + 6 in the mix"
            " rooms) x env.max_decisions=30)",
        ),
    ],
)
def test_a_k_that_gathering_cannot_reach_is_refused_before_compute(train_config, tmp_path, overrides, message):
    with pytest.raises(ValueError) as error:
        train(train_config("logger=none", *overrides), run_dir=tmp_path)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert not any(tmp_path.iterdir()), "nothing is computed or written"


def test_the_mix_rooms_states_count_towards_k(train_config, tmp_path):
    """K = 1300 with a 6-agent mix room beside the 20-agent room: gathering records 2 x 26 x 30 = 1560 states per
    process, so the run trains (it was refused as above 1200)."""
    cfg = train_config(
        "algo=vqql",
        "logger=none",
        "vq.num_prototypes=1300",
        "+mix=[{name: corridor, length: 40.0, width: 2.0, agents: 6}]",
    )
    train(cfg, run_dir=tmp_path)
    assert (tmp_path / "checkpoints" / "last.safetensors").exists()


@pytest.mark.parametrize(
    ("overrides", "every"),
    [
        (("algo=vqql", "vq.num_prototypes=1200"), "every process's quantizer uses K = "),  # 2 x 20 agents x 30
        (("algo=in_vqql", "vq.num_prototypes=60"), "every process's quantizer uses K = "),  # stage 1: 2 x 1 x 30
        (("algo=vqql", "vq.num_prototypes=2400", "vq.per_process=false"), "the quantizer uses K = "),
    ],
)
def test_fewer_distinct_states_than_k_shrink_k_with_one_line(train_config, tmp_path, overrides, every):
    """Agents that reach the door stop adding states: K shrinks to what the states hold, the same K in every process
    (their tables stack), with one one-line warning per phase that shrinks, and the run goes on (it used to fail
    after gathering)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = train(train_config("logger=none", "algo.trials=2", *overrides), run_dir=tmp_path)
    shrinks = [w for w in caught if issubclass(w.category, UserWarning) and "distinct" in str(w.message)]
    assert shrinks and all(w.category is PedrlWarning for w in shrinks), [str(w.message) for w in shrinks]
    phases = [str(w.message).split(" (")[0] for w in shrinks]
    assert len(set(phases)) == len(phases), phases  # at most one line per phase
    message = str(shrinks[0].message)
    assert message.startswith("phase 1 (") and every in message and "\n" not in message
    fitted = int(message.split("uses K = ")[1].split()[0])
    assert fitted < int(overrides[1].split("=")[1])
    assert result.phases[0]["prototypes"] == fitted
    tensors = load_checkpoint(tmp_path / "checkpoints" / "iter_0001.safetensors").tensors
    assert tensors["q_values"].shape[2] == fitted


def test_a_shrink_warning_prints_as_one_line():
    with pytest.warns(PedrlWarning, match="^K shrank$"):
        warn("K shrank\nsecond line")  # the first line only; installs the one-line format
    assert warnings.formatwarning("K shrank", PedrlWarning, __file__, 1) == "pedrl: warning: K shrank\n"
    assert "UserWarning" in warnings.formatwarning("other", UserWarning, __file__, 1)  # others keep Python's format
