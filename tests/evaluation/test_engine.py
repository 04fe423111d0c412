"""The scaled evaluation (:func:`pedrl.evaluation.evaluate`) end to end, from tiny checkpoints of every algorithm:
the engine's trials and figures, the report's files, ``controller=jupedsim`` and the eval config's checks.

The ``pedrl-eval`` entry point's refusals are in ``tests/test_evaluate.py``; the controllers are tested in
``tests/algos/test_controllers.py``.
"""

import json
import sqlite3
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import open_dict

from pedrl._numba import numba_available
from pedrl.analysis import RoomGeometry, read_pedpy_trajectory
from pedrl.cli import CONFIG_DIR
from pedrl.evaluation import SCALING_COLUMNS, evaluate, print_table
from pedrl.io import CheckpointError, read_csv
from pedrl.scenarios import paper_room
from pedrl.sim.motion import MOTION_MODELS, Simultaneous
from pedrl.train import train

REQUIRED_COLUMNS = ("agents", "fails_pct", "fails_std", "mean_speed", "speed_std")
# Two learning agents (A = 2) per checkpoint, so evaluating 3 and 5 agents replicates tables.
TRAIN_OVERRIDES = {
    "vqql": ["algo=vqql", "algo.num_agents=2", "algo.iterations=1"],
    "it_vqql": ["algo=it_vqql", "algo.num_agents=2"],
    "in_vqql": ["algo=in_vqql", "algo.stages=[1,2]"],
}
EVAL_AGENTS = (3, 5)
PROCESSES = 2  # debug=default trains 2 learning processes


def compose_config(name: str, overrides: list[str]):
    # the module-scoped fixture below cannot use the function-scoped `compose` fixture of conftest
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        return compose(config_name=name, overrides=overrides)


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """Tiny tensors run fastest on one thread (and a busy machine makes more threads much slower)."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory, one_thread) -> dict[str, Path]:
    """``last.safetensors`` of a seconds-long training run of each algorithm."""
    paths = {}
    for algo, overrides in TRAIN_OVERRIDES.items():
        cfg = compose_config(
            "train",
            [
                "debug=default",
                *overrides,
                "algo.trials=4",
                "vq.num_prototypes=8",
                "env.max_decisions=15",
                "logger=none",
                "threads=1",
            ],
        )
        with open_dict(cfg):
            cfg.progress = False
        run_dir = tmp_path_factory.mktemp(algo)
        train(cfg, run_dir=run_dir)
        paths[algo] = run_dir / "checkpoints" / "last.safetensors"
    return paths


def eval_config(checkpoint: Path, *overrides: str):
    return compose_config(
        "eval",
        [
            f"checkpoint={checkpoint}",
            f"agents=[{','.join(map(str, EVAL_AGENTS))}]",
            "trials=2",
            "trials_per_batch=1",
            "animation.max_frames=3",
            "threads=1",
            *overrides,
        ],
    )


# ---------------------------------------------------------------------- end to end
@pytest.mark.parametrize("algo", list(TRAIN_OVERRIDES))
def test_replicated_evaluation_writes_every_output(algo, checkpoints, tmp_path):
    rows = evaluate(eval_config(checkpoints[algo]), run_dir=tmp_path)

    table = read_csv(tmp_path / "scaling.csv")
    assert list(table[0]) == list(SCALING_COLUMNS)
    assert set(REQUIRED_COLUMNS) <= set(table[0])
    # the greedy reference beside the learned crowd by default, its own outputs in greedy/
    both = [(c, n) for c in ("learned", "greedy") for n in EVAL_AGENTS]
    assert [(r["controller"], int(r["agents"])) for r in table] == both
    assert [(r["controller"], r["agents"]) for r in rows] == both
    assert [r["controller"] for r in read_csv(tmp_path / "greedy" / "scaling.csv")] == ["greedy"] * len(EVAL_AGENTS)
    assert (tmp_path / "greedy" / "fundamental_diagram.png").exists()
    for row, written in zip(rows, table, strict=True):
        assert row["trials"] == 2 * PROCESSES == int(written["trials"])
        assert 0.0 <= row["fails_pct"] <= 100.0 and row["fails_std"] >= 0.0
        assert 0.0 <= row["mean_speed"] <= 2.5 and row["speed_std"] >= 0.0
        assert row["crashes_per_agent"] >= 0.0 and row["wall_crashes_per_agent"] >= 0.0
        assert 0 <= row["evacuated_trials"] <= row["trials"]
        if row["evacuated_trials"]:
            assert 0.0 < row["evacuation_time_s"] <= 15.0  # debug=default: 15 decisions of 1 s
        if not np.isnan(row["door_flow"]):
            assert row["door_flow"] > 0.0
        assert float(written["fails_pct"]) == pytest.approx(row["fails_pct"], rel=1e-5)

    def reject(constant):
        raise ValueError(f"{constant} is not JSON")

    written = json.loads((tmp_path / "scaling.json").read_text(), parse_constant=reject)
    assert [(r["controller"], r["agents"]) for r in written] == both

    diagram = read_csv(tmp_path / "fundamental_diagram.csv")
    assert (tmp_path / "fundamental_diagram.csv").read_text().splitlines()[0] == "agents,trial,frame,density,speed,flow"
    for sample in diagram:
        assert int(sample["agents"]) in EVAL_AGENTS and 0 <= int(sample["trial"]) < 2 * PROCESSES
        assert float(sample["density"]) >= 0.05 and 0.0 <= float(sample["speed"]) <= 2.5 + 1e-5
        assert float(sample["flow"]) == pytest.approx(float(sample["density"]) * float(sample["speed"]), rel=1e-4)
    for name in ["fundamental_diagram.png", *(f"density_map_{n}.png" for n in EVAL_AGENTS)]:
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    for n in EVAL_AGENTS:
        counts = np.load(tmp_path / f"density_map_{n}.npy")
        assert counts.shape == (10, 10) and counts.dtype == np.int64 and counts.min() >= 0  # 10 m x 10 m room
        # frame 0 alone puts every agent of every trial in the room
        assert counts.sum() >= n * 2 * PROCESSES
        assert (tmp_path / f"animation_{n}.gif").read_bytes()[:4] == b"GIF8"
        exported = sorted(p.name for p in (tmp_path / "trajectories" / f"agents_{n}").iterdir())
        # export.trials = 2, each in PedPy's text format and as a JuPedSim SQLite file
        assert exported == ["trial_000.sqlite", "trial_000.txt", "trial_001.sqlite", "trial_001.txt"]
        ids, frames, _, framerate = read_pedpy_trajectory(tmp_path / "trajectories" / f"agents_{n}" / exported[1])
        assert framerate == 1.0 and sorted(ids[frames == 0]) == list(range(n))
        with sqlite3.connect(tmp_path / "trajectories" / f"agents_{n}" / exported[0]) as connection:
            rows = connection.execute("SELECT id, pos_x, pos_y FROM trajectory_data WHERE frame = 0").fetchall()
        assert sorted(row[0] for row in rows) == list(range(n))
    assert (tmp_path / "trajectories" / "geometry.wkt").read_text().startswith("POLYGON ((0.0 0.0, 10.0 0.0")
    assert any(p.name.startswith("events.out.tfevents") for p in (tmp_path / "tb").iterdir())


def test_tensorboard_holds_scalars_and_figures(checkpoints, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    evaluate(eval_config(checkpoints["vqql"], "animation.enabled=false"), run_dir=tmp_path)
    events = EventAccumulator(str(tmp_path / "tb"))
    events.Reload()
    assert [s.step for s in events.Scalars("eval/fails_pct")] == list(EVAL_AGENTS)
    assert {"eval/mean_speed", "eval/door_flow", "eval/crashes_per_agent"} <= set(events.Tags()["scalars"])
    assert {"eval/fundamental_diagram", *(f"eval/density_map_{n}" for n in EVAL_AGENTS)} <= set(events.Tags()["images"])
    assert not list(tmp_path.glob("animation_*.gif"))


def test_density_map_counts_every_recorded_agent_frame_in_the_room(checkpoints, tmp_path):
    trials = 3
    cfg = eval_config(
        checkpoints["it_vqql"], "agents=[4]", f"trials={trials}", "trials_per_batch=2", f"export.trials={trials * 9}"
    )
    evaluate(cfg, run_dir=tmp_path)
    files = sorted((tmp_path / "trajectories" / "agents_4").glob("*.txt"))
    # every simulated trial is exported: trials x processes, batches of 2 trials per process (the last one cut)
    assert [p.name for p in files] == [f"trial_{i:03d}.txt" for i in range(trials * PROCESSES)]
    room = RoomGeometry(width=10.0, length=10.0, door_width=3.0)
    inside = sum(int(room.contains(read_pedpy_trajectory(p)[2]).sum()) for p in files)
    counts = np.load(tmp_path / "density_map_4.npy")
    assert counts.sum() == inside
    assert inside > 4 * trials * PROCESSES


def test_exported_trials_open_in_pedpy(checkpoints, tmp_path):
    pedpy = pytest.importorskip("pedpy")
    import shapely

    cfg = eval_config(checkpoints["vqql"], "agents=[5]", "animation.enabled=false", "export.fps=4")
    evaluate(cfg, run_dir=tmp_path)
    walkable = pedpy.WalkableArea((tmp_path / "trajectories" / "geometry.wkt").read_text())
    door = pedpy.MeasurementLine([(3.5, 10.0), (6.5, 10.0)])  # the debug room: 10 m x 10 m, a 3 m door at y = 10
    counted = 0
    for path in sorted((tmp_path / "trajectories" / "agents_5").glob("*.txt")):
        trajectory = pedpy.load_trajectory_from_txt(trajectory_file=path)
        assert trajectory.frame_rate == 4.0 and set(trajectory.data["id"]) <= set(range(5))
        points = shapely.points(trajectory.data[["x", "y"]].to_numpy())
        assert shapely.covers(walkable.polygon, points).all()  # including agents in the door's exit frames
        # PedPy counts over the door every walker whose rows reach past it
        left = set(trajectory.data.loc[trajectory.data["y"] >= 10.0, "id"])
        _, crossings = pedpy.compute_n_t(traj_data=trajectory, measurement_line=door)
        assert set(crossings["id"]) == left
        counted += len(left)
        # the same trial as a JuPedSim SQLite file, which carries its own walkable area
        sqlite = path.with_suffix(".sqlite")
        from_sqlite = pedpy.load_trajectory_from_jupedsim_sqlite(trajectory_file=sqlite)
        assert from_sqlite.frame_rate == 4.0 and len(from_sqlite.data) == len(trajectory.data)
        area = pedpy.load_walkable_area_from_jupedsim_sqlite(trajectory_file=sqlite)
        assert area.polygon.equals(walkable.polygon)
    assert counted > 0


def test_evaluation_is_deterministic_for_a_seed(checkpoints, tmp_path):
    cfg = eval_config(checkpoints["it_vqql"], "epsilon=0.1", "animation.enabled=false", "tensorboard=false")
    evaluate(cfg, run_dir=tmp_path / "a")
    evaluate(cfg, run_dir=tmp_path / "b")
    assert (tmp_path / "a" / "scaling.csv").read_text() == (tmp_path / "b" / "scaling.csv").read_text()
    for name in ("fundamental_diagram.csv", "trajectories/agents_5/trial_001.txt"):
        assert (tmp_path / "a" / name).read_text() == (tmp_path / "b" / name).read_text(), name
    assert np.array_equal(np.load(tmp_path / "a" / "density_map_5.npy"), np.load(tmp_path / "b" / "density_map_5.npy"))

    evaluate(eval_config(checkpoints["it_vqql"], "seed=1", "tensorboard=false"), run_dir=tmp_path / "c")
    first = (tmp_path / "a" / "trajectories" / "agents_5" / "trial_000.txt").read_text()
    assert (tmp_path / "c" / "trajectories" / "agents_5" / "trial_000.txt").read_text() != first


def test_greedy_baseline_runs_on_the_same_scenarios(checkpoints, tmp_path, capsys):
    common = ("animation.enabled=false", "tensorboard=false")
    rows = evaluate(eval_config(checkpoints["in_vqql"], *common), run_dir=tmp_path)
    for n in EVAL_AGENTS:
        for trial in ("trial_000.txt", "trial_001.txt"):
            a = read_pedpy_trajectory(tmp_path / "trajectories" / f"agents_{n}" / trial)
            b = read_pedpy_trajectory(tmp_path / "greedy" / "trajectories" / f"agents_{n}" / trial)
            assert np.array_equal(a[2][a[1] == 0], b[2][b[1] == 0])  # frame 0: the same initial positions
            assert len(a[2][a[1] == 0]) == n
    greedy = [r for r in rows if r["controller"] == "greedy"]
    for row in greedy:
        assert 0.0 <= row["fails_pct"] <= 100.0 and 0.0 <= row["mean_speed"] <= 2.5
    # the reference alone gives the same numbers as beside the learned crowd: the same scenes and draws
    alone = evaluate(eval_config(checkpoints["in_vqql"], "controller=greedy", *common), run_dir=tmp_path / "alone")
    assert alone == greedy
    # two rows per agent count on the console, learned first
    print_table(rows, "both")
    lines = [line.split("|")[:2] for line in capsys.readouterr().out.splitlines() if line.count("|") > 4][1:]
    expected = [[f"{n:>6}", f"{c:>10}"] for n in EVAL_AGENTS for c in ("learned", "greedy")]
    assert [[a.strip(), b.strip()] for a, b in lines] == [[e.strip() for e in pair] for pair in expected]


def test_the_headline_is_at_epsilon_zero_with_the_greedy_walker_beside_it():
    """The eval defaults: no random actions (a share of them is a sensitivity, not the model), greedy beside."""
    cfg = compose_config("eval", ["checkpoint=x"])
    assert cfg.epsilon == 0.0 and list(cfg.references) == ["greedy"] and cfg.controller == "learned"


def test_references_can_be_switched_off(checkpoints, tmp_path):
    rows = evaluate(eval_config(checkpoints["vqql"], "references=[]", "animation.enabled=false"), run_dir=tmp_path)
    assert {r["controller"] for r in rows} == {"learned"} and not (tmp_path / "greedy").exists()


def test_jupedsim_runs_on_the_same_scenes_and_reports_the_table(checkpoints, tmp_path, capsys):
    pytest.importorskip("jupedsim")
    common = ("agents=[5]", "trials=1", "animation.enabled=false", "tensorboard=false")
    rows = evaluate(eval_config(checkpoints["vqql"], "references=[greedy,jupedsim]", *common), run_dir=tmp_path)
    assert [r["controller"] for r in rows] == ["learned", "greedy", "jupedsim"]

    row = rows[-1]
    assert row["agents"] == 5 and row["trials"] == PROCESSES  # one trial per process, as the other controllers
    assert 0.0 <= row["fails_pct"] <= 100.0 and row["fails_std"] >= 0.0
    assert 0.5 < row["mean_speed"] <= 1.2 + 1e-6  # JuPedSim's default desired speed
    assert 0.0 <= row["stuck_pct"] <= row["fails_pct"] + 1e-9
    if row["evacuated_trials"]:
        assert 0.0 < row["evacuation_time_s"] <= 15.0  # debug=default: 15 decisions of 1 s
    assert np.isnan(row["crashes_per_agent"]) and np.isnan(row["wall_crashes_per_agent"])  # n/a: no cut moves
    assert json.loads((tmp_path / "jupedsim" / "scaling.json").read_text())[0]["crashes_per_agent"] is None
    for trial in ("trial_000.txt", "trial_001.txt"):
        a = read_pedpy_trajectory(tmp_path / "greedy" / "trajectories" / "agents_5" / trial)
        b = read_pedpy_trajectory(tmp_path / "jupedsim" / "trajectories" / "agents_5" / trial)
        assert np.allclose(a[2][a[1] == 0], b[2][b[1] == 0])  # frame 0: the same initial positions
        assert b[3] == 1.0  # one frame per decision
    assert (tmp_path / "jupedsim" / "fundamental_diagram.png").exists()
    print_table(rows, "jupedsim")
    assert "n/a" in capsys.readouterr().out


def test_jupedsim_refuses_a_decision_that_is_no_whole_number_of_its_steps(checkpoints, tmp_path):
    pytest.importorskip("jupedsim")
    with pytest.raises(ValueError) as error:
        evaluate(eval_config(checkpoints["vqql"], "controller=jupedsim", "jupedsim.dt=0.03"), run_dir=tmp_path)
    assert "jupedsim.dt=0.03 is invalid" in str(error.value) and "\n" not in str(error.value)
    assert not (tmp_path / "scaling.csv").exists()  # nothing ran


def test_jupedsim_without_jupedsim_fails_with_one_line(checkpoints, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "jupedsim", None)  # not importable
    with pytest.raises(ValueError) as error:
        evaluate(eval_config(checkpoints["vqql"], "controller=jupedsim"), run_dir=tmp_path)
    assert (
        str(error.value)
        == "controller=jupedsim is invalid here: jupedsim is not installed: pip install 'pedrl[jupedsim]'"
    )
    with pytest.raises(ValueError, match=r"^references=jupedsim is invalid here"):
        evaluate(eval_config(checkpoints["vqql"], "references=[greedy,jupedsim]"), run_dir=tmp_path)


# ---------------------------------------------------------------------- bad values (pedrl.evaluation.config)
@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("agents=[0]", "agents=[0] is invalid"),
        ("agents=[]", "agents=[] is invalid"),
        ("controller=foo", "controller='foo' is invalid"),
        ("jupedsim.model=foo", "jupedsim.model='foo' is invalid"),
        ("jupedsim.desired_speed=0", "jupedsim.desired_speed=0 is invalid"),
        ("jupedsim.desired_speed=1e6", "jupedsim.desired_speed=1000000.0 is invalid: must be a number in (0, 10]"),
        ("jupedsim.time_gap=0.05", "jupedsim.time_gap=0.05 is invalid: must be a number in [0.1, 10]"),
        ("epsilon=2", "epsilon=2 is invalid"),
        ("references=[foo]", "references='foo' is invalid: must be one of greedy, jupedsim"),
        ("references=[learned]", "references='learned' is invalid"),
        ("references=greedy", "references='greedy' is invalid: must be a list"),
        ("trials=0", "trials=0 is invalid"),
        ("density_map.tile_size=0", "density_map.tile_size=0 is invalid"),
        ("agents=[1000]", "num_agents=1000 is invalid"),
        ("fused=yes", "fused='yes' is invalid: must be true, false or null"),
    ],
)
def test_bad_values_fail_with_one_line(override, message, checkpoints, tmp_path):
    with pytest.raises(ValueError) as error:
        evaluate(eval_config(checkpoints["vqql"], override), run_dir=tmp_path)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert not (tmp_path / "scaling.csv").exists()  # nothing ran


def test_missing_checkpoint_argument_and_foreign_files(tmp_path):
    cfg = compose_config("eval", [])
    with pytest.raises(ValueError, match="checkpoint is missing"):
        evaluate(cfg, run_dir=tmp_path)
    from safetensors.torch import save_file

    foreign = tmp_path / "foreign.safetensors"
    save_file({"weights": torch.zeros(2)}, str(foreign))
    with pytest.raises(CheckpointError, match="not a pedrl checkpoint"):
        evaluate(eval_config(foreign), run_dir=tmp_path)


# ---------------------------------------------------------------------- stuck agents and contacts (the engine)
def test_stuck_agents_are_those_left_in_the_room_that_did_not_move_in_the_last_20_decisions():
    from pedrl.evaluation import stuck_agents

    frames = 41
    positions = np.zeros((1, frames, 4, 2))
    positions[0, :, 0, 0] = np.arange(frames) * 1.0  # walked all along: not stuck
    positions[0, :20, 1, 0] = np.arange(20) * 1.0  # walked, then stood still for the last 21 frames: stuck
    positions[0, 20:, 1, 0] = 19.0
    positions[0, :, 2, 0] = np.arange(frames) * 0.01  # crept 0.2 m in the last 20 decisions: stuck
    positions[0, :, 3, 0] = 5.0  # stood still, but it left the room (its row is padding): not stuck
    in_room = np.array([[True, True, True, False]])
    assert stuck_agents(positions, in_room).tolist() == [[False, True, True, False]]


def test_evaluation_reports_stuck_agents_and_evacuated_trials(checkpoints, tmp_path):
    rows = evaluate(eval_config(checkpoints["vqql"], "animation.enabled=false"), run_dir=tmp_path)
    for row in rows:
        assert 0.0 <= row["stuck_pct"] <= row["fails_pct"] + 1e-9  # a stuck agent is one that failed
        assert row["evacuated_pct"] == pytest.approx(100.0 * row["evacuated_trials"] / row["trials"])


def test_contacts_count_bodies_and_walls_apart():
    """A lone walker running straight at full speed in a small room hits walls and never a body; two walkers put
    face to face hit each other: each lands in its own column."""
    from pedrl.evaluation.engine import record_batch

    class Straight:
        def act(self, env, obs, info):
            return torch.full(env.active.shape, 8 * 9 + 4)  # full speed up, no turn

    alone = paper_room(width=4.0, length=4.0, door_width=1.0).room(num_replicas=8, num_agents=1, max_decisions=10)
    record = record_batch(alone, Straight())
    assert record.crashes.sum() == 0 and record.wall_crashes.sum() > 0

    pair = paper_room(width=10.0, length=10.0).room(num_replicas=1, num_agents=2, max_decisions=3)
    east, west = 0.0, float(np.pi)
    options = {"positions": [[[3.0, 5.0], [5.0, 5.0]]], "headings": [[east, west]], "speeds": [[2.5, 2.5]]}
    with pytest.MonkeyPatch.context() as patch:
        original = pair.reset
        patch.setattr(pair, "reset", lambda **kwargs: original(seed=0, options=options))
        record = record_batch(pair, Straight())
    assert record.crashes[0].min() >= 1 and record.wall_crashes.sum() == 0


# ---------------------------------------------------------------------- the fast path (fused trial kernels)
def sparse_room(rule: str = "stop"):
    """Few walkers in a wide room, acting nearest the door first: both paths must walk the same trajectories."""
    return paper_room(width=30.0, length=20.0, door_width=6.0).room(
        num_replicas=3, num_agents=4, max_decisions=40, motion=MOTION_MODELS[rule](order="door_first")
    )


@pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")
@pytest.mark.parametrize("rule", ["stop", "yield"])
def test_the_greedy_walker_records_the_same_trials_on_both_paths(rule):
    """Where the order of action is the goal distance's (door_first), the fused recording of the greedy walker is
    the torch loop's within the fused trial's tolerances (positions 1e-4 m), frame by frame, with the same exits,
    times, speeds and contacts."""
    from pedrl.evaluation.engine import record_batch
    from pedrl.sim.controllers import GreedyDoorController

    records = []
    for fused in (False, True):
        env = sparse_room(rule)
        env.reset(seed=3)
        records.append(record_batch(env, GreedyDoorController(), fused=fused))
    torch_path, kernels = records
    assert torch_path.positions.shape == kernels.positions.shape and torch_path.left.all()
    np.testing.assert_allclose(kernels.positions, torch_path.positions, atol=1e-4, rtol=0)
    assert np.array_equal(kernels.in_room, torch_path.in_room) and np.array_equal(kernels.left, torch_path.left)
    np.testing.assert_allclose(kernels.exit_time, torch_path.exit_time, rtol=0, atol=1e-6)
    np.testing.assert_allclose(kernels.speed_sum, torch_path.speed_sum, rtol=1e-5)
    np.testing.assert_allclose(kernels.speed_sq_sum, torch_path.speed_sq_sum, rtol=1e-5)
    assert np.array_equal(kernels.speed_count, torch_path.speed_count)
    assert np.array_equal(kernels.crashes, torch_path.crashes)
    assert np.array_equal(kernels.wall_crashes, torch_path.wall_crashes)


@pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")
def test_the_fast_path_is_on_by_default_and_agrees_with_the_torch_loop(checkpoints, tmp_path):
    """pedrl-eval's default records through the kernels: the same scenes, a seed gives the same tables, and the
    headline figures agree with the torch loop's within the spread of the trials."""
    common = ("animation.enabled=false", "tensorboard=false", "trials=24", "references=[]")
    fast = evaluate(eval_config(checkpoints["it_vqql"], *common), run_dir=tmp_path / "a")
    again = evaluate(eval_config(checkpoints["it_vqql"], *common), run_dir=tmp_path / "b")
    reference = evaluate(eval_config(checkpoints["it_vqql"], *common, "fused=false"), run_dir=tmp_path / "c")
    assert (tmp_path / "a" / "scaling.csv").read_text() == (tmp_path / "b" / "scaling.csv").read_text()
    assert fast == again
    for mine, theirs in zip(fast, reference, strict=True):
        assert mine["agents"] == theirs["agents"]
        error = ((mine["fails_std"] ** 2 + theirs["fails_std"] ** 2) / theirs["trials"]) ** 0.5
        assert abs(mine["fails_pct"] - theirs["fails_pct"]) <= 3 * error + 1e-9, (mine, theirs)  # 3 standard errors


def test_fused_true_is_refused_in_one_line_where_the_kernels_cannot_run(tmp_path, monkeypatch):
    from pedrl.evaluation.engine import check_fused_controller
    from pedrl.sim.controllers import GreedyDoorController

    env = paper_room(width=10.0, length=10.0).room(num_replicas=2, num_agents=4, motion=Simultaneous())
    with pytest.raises(
        ValueError, match=r"^fused=true is invalid: the fused trial cannot run with motion=simultaneous"
    ):
        check_fused_controller(GreedyDoorController(), [env])
