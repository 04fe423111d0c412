"""pedrl-plot: learning curves of several runs together, read from hand-made and real learning_curve.csv files;
and the plot part of the bad-input catalogue (:mod:`tests.refusals`)."""

import csv
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import open_dict

import pedrl.plot
from pedrl.algos.records import CURVE_COLUMNS
from pedrl.cli import CONFIG_DIR
from pedrl.learning_curves import (
    check_marks,
    draw_marks,
    draw_phases,
    draw_runs,
    plot_runs,
    read_learning_curve,
    read_phases,
)
from pedrl.train import train
from tests.refusals import (
    assert_nothing_computed,
    assert_refused,
    binary_curve,
    catalogue,
    read_only_folder,
    run_hydra_main,
    write_small_curve,
)

DEBUG_RUNS = {"VQQL": "vqql", "IT-VQQL": "it_vqql", "IN-VQQL": "in_vqql"}


def write_curve(path, phases, success, *, std=None):
    """A learning_curve.csv as pedrl-train writes it, with the given phase and success_rate_mean per trial."""
    path.parent.mkdir(parents=True, exist_ok=True)
    std = std if std is not None else [0.1] * len(success)
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CURVE_COLUMNS)
        writer.writeheader()
        trial = 0
        for i, (phase, value) in enumerate(zip(phases, success, strict=True)):
            trial = 0 if i == 0 or phases[i - 1] != phase else trial + 1
            row = {column: 0.0 for column in CURVE_COLUMNS}
            row.update(phase=phase, agents=20, trial=trial, global_trial=i, success_rate_mean=value)
            row.update(success_rate_std=std[i])
            writer.writerow(row)
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Debug-sized runs of VQQL (2 blocks of 10 trials), IT-VQQL (2 x 10) and IN-VQQL (stages 1, 2, 4 x 10)."""
    root = tmp_path_factory.mktemp("runs")
    made = {}
    for label, algo in DEBUG_RUNS.items():
        with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
            cfg = compose("train", ["debug=default", f"algo={algo}", "logger=none"])
        with open_dict(cfg):
            cfg.progress = False
        train(cfg, run_dir=root / algo)
        made[label] = root / algo
    return made


# ---------------------------------------------------------------------- read_learning_curve on hand-made files
def test_boundaries_are_the_first_trials_of_every_new_phase(tmp_path):
    path = write_curve(tmp_path / "learning_curve.csv", [1, 1, 1, 2, 2, 3, 3, 3], [0.0] * 8)
    trials, mean, std, boundaries = read_learning_curve(path)
    assert trials.tolist() == list(range(8))
    assert boundaries == [3.0, 5.0]
    # the run directory is accepted as well as the CSV itself
    assert read_learning_curve(tmp_path)[3] == [3.0, 5.0]


def test_moving_average_is_trailing_and_restarts_at_every_phase(tmp_path):
    phases = [1, 1, 1, 1, 2, 2, 2]
    success = [0.0, 0.3, 0.6, 0.9, 0.2, 0.4, 1.0]
    std = [0.2, 0.4, 0.0, 0.2, 0.1, 0.3, 0.5]
    path = write_curve(tmp_path / "learning_curve.csv", phases, success, std=std)
    _, mean, smoothed_std, _ = read_learning_curve(path, smooth=3)
    # phase 1: 0 | (0 + .3)/2 | (0 + .3 + .6)/3 | (.3 + .6 + .9)/3; phase 2 starts again from its own first trial
    expected = [0.0, 0.15, 0.3, 0.6, 0.2, 0.3, (0.2 + 0.4 + 1.0) / 3]
    np.testing.assert_allclose(mean, expected, atol=1e-12)
    np.testing.assert_allclose(smoothed_std, [0.2, 0.3, 0.2, 0.2, 0.1, 0.2, 0.3], atol=1e-12)
    # smooth=1 leaves the values as written; a window longer than a phase averages the whole phase so far
    np.testing.assert_allclose(read_learning_curve(path, smooth=1)[1], success)
    np.testing.assert_allclose(read_learning_curve(path, smooth=100)[1][3], 0.45)


def test_phases_are_read_each_from_its_own_first_trial(tmp_path):
    path = write_curve(tmp_path / "learning_curve.csv", [1, 1, 1, 2, 2, 3], [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    phases = read_phases(path, smooth=2)
    assert [(phase, agents, trials.tolist()) for phase, agents, trials, _, _ in phases] == [
        (1, 20, [0.0, 1.0, 2.0]),
        (2, 20, [0.0, 1.0]),
        (3, 20, [0.0]),
    ]
    # the same smoothed values as the whole curve's, cut at the boundaries
    _, whole, _, _ = read_learning_curve(path, smooth=2)
    np.testing.assert_allclose(np.concatenate([mean for *_, mean, _ in phases]), whole)
    np.testing.assert_allclose(phases[1][3], [0.4, 0.45])


def test_other_metrics_are_read(tmp_path):
    path = write_curve(tmp_path / "learning_curve.csv", [1, 1], [0.5, 0.5])
    trials, mean, std, _ = read_learning_curve(path, metric="crashes_wall")
    assert mean.tolist() == [0.0, 0.0] and trials.tolist() == [0.0, 1.0]


@pytest.mark.parametrize(
    ("make", "kwargs", "message"),
    [
        (lambda d: d / "missing", {}, "no learning curve at"),
        (lambda d: write_curve(d / "learning_curve.csv", [], []), {}, "has no rows yet"),
        (lambda d: write_curve(d / "learning_curve.csv", [1], [0.5]), {"metric": "happiness"}, "metric='happiness'"),
        (lambda d: write_curve(d / "learning_curve.csv", [1], [0.5]), {"smooth": 0}, "smooth=0 is invalid"),
        (lambda d: _malformed(d / "learning_curve.csv"), {}, "is malformed"),
    ],
)
def test_bad_input_is_a_value_error(tmp_path, make, kwargs, message):
    with pytest.raises(ValueError, match=message):
        read_learning_curve(make(tmp_path), **kwargs)


def _malformed(path):
    write_curve(path, [1, 1], [0.5, 0.5])
    text = path.read_text().splitlines()
    text[2] = text[2].replace("0.5", "not-a-number", 1)
    path.write_text("\n".join(text) + "\n")
    return path


# ---------------------------------------------------------------------- real runs of the three algorithms together
def test_three_algorithms_are_drawn_together_with_their_phase_boundaries(runs):
    axes = draw_runs(list(runs.values()), labels=list(runs))
    curves = {line.get_label(): line for line in axes.get_lines() if not line.get_label().startswith("_")}
    assert sorted(curves) == sorted(runs)
    # debug runs: VQQL 2 blocks of 10 trials, IT-VQQL 2 iterations of 10, IN-VQQL 3 stages of 10
    assert {label: len(line.get_xdata()) for label, line in curves.items()} == {
        "VQQL": 20,
        "IT-VQQL": 20,
        "IN-VQQL": 30,
    }
    dashed = [line for line in axes.get_lines() if line.get_linestyle() == "--"]
    boundaries = {}
    for line in dashed:
        boundaries.setdefault(line.get_color(), []).append(line.get_xdata()[0])
    # each run's boundaries are drawn in its own curve's colour: VQQL blocks and IT iterations at 10, IN at 10, 20
    assert sorted(boundaries[curves["VQQL"].get_color()]) == [10]
    assert sorted(boundaries[curves["IT-VQQL"].get_color()]) == [10]
    assert sorted(boundaries[curves["IN-VQQL"].get_color()]) == [10, 20]
    assert [t.get_text() for t in axes.get_legend().get_texts()] == list(runs)


def test_phases_layout_draws_each_phase_from_zero_and_one_phase_runs_dashed(runs, tmp_path):
    one_phase = write_curve(tmp_path / "vqql" / "learning_curve.csv", [1] * 12, [0.4] * 12).parent
    axes = draw_phases([runs["IN-VQQL"], runs["IT-VQQL"], one_phase], labels=["IN", "IT", "VQQL"])
    curves = {line.get_label(): line for line in axes.get_lines() if not line.get_label().startswith("_")}
    # debug runs: IN-VQQL stages of 1, 2 and 4 agents, IT-VQQL 2 iterations of 20 agents, 10 trials each
    # the stages say how many agents learn in each; the iterations, all of 20 agents, do not
    assert list(curves) == ["IN 1 (1 agent)", "IN 2 (2 agents)", "IN 3 (4 agents)", "IT 1", "IT 2", "VQQL"]
    assert all(list(line.get_xdata()) == list(range(10)) for label, line in curves.items() if label != "VQQL")
    assert list(curves["VQQL"].get_xdata()) == list(range(12)) and curves["VQQL"].get_linestyle() == "--"
    # a colour per phase from dark to light, the second phased run in its own line style
    assert len({curves[f"IN {k}"].get_color() for k in ("1 (1 agent)", "2 (2 agents)", "3 (4 agents)")}) == 3
    assert curves["IN 1 (1 agent)"].get_linestyle() == "-" and curves["IT 1"].get_linestyle() == ":"
    assert axes.get_xlabel() == "trials within the phase"
    # the only reference is black; two references keep colours of their own
    assert curves["VQQL"].get_color() == "black"
    other = write_curve(tmp_path / "vqql_b" / "learning_curve.csv", [1] * 5, [0.3] * 5).parent
    axes = draw_phases([one_phase, other], labels=["A", "B"])
    colours = [line.get_color() for line in axes.get_lines() if not line.get_label().startswith("_")]
    assert len(set(colours)) == 2 and "black" not in colours


def test_a_bound_on_the_trials_is_a_dotted_vertical_line(runs):
    axes = draw_marks(draw_runs([runs["IN-VQQL"]]), check_marks([[15, None, "within 1.5e5"], [5, 0.4, "end"]]))
    bounds = [line for line in axes.get_lines() if line.get_linestyle() == ":"]
    assert len(bounds) == 1 and list(bounds[0].get_xdata()) == [15, 15]
    assert [text.get_text() for text in axes.texts] == ["within 1.5e5", "end"]
    assert len([line for line in axes.get_lines() if line.get_marker() == "*"]) == 1


def test_plot_runs_writes_a_figure_without_layout_warnings(runs, tmp_path):
    for layout in ("whole", "phases"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            path = plot_runs(list(runs.values()), tmp_path / "out" / f"{layout}.png", smooth=5, layout=layout)
        assert path.is_file() and path.stat().st_size > 10_000


def test_marks_are_drawn_as_stars_with_their_text(runs, tmp_path):
    axes = draw_marks(draw_runs(list(runs.values())), check_marks([[40, 0.4, "Figure 4: near 0.4"]]))
    stars = [line for line in axes.get_lines() if line.get_marker() == "*"]
    assert len(stars) == 1 and list(stars[0].get_xdata()) == [40.0] and list(stars[0].get_ydata()) == [0.4]
    assert [text.get_text() for text in axes.texts] == ["Figure 4: near 0.4"]
    path = plot_runs(list(runs.values()), tmp_path / "marked.png", marks=[[40, 0.4, "end"]])
    assert path.is_file()


@pytest.mark.parametrize(
    ("mark", "fragment"),
    [
        ([1, 2], "marks[0]=[1, 2] is invalid: must be [trials, value or null, 'text']"),
        ("abc", "marks[0]='abc' is invalid: must be [trials, value or null, 'text']"),
        ([1, 2, 3], "marks[0]=[1, 2, 3] is invalid: its text must be a string of at most 200 characters, got 3"),
        (["a", 0.4, "x"], "its trials 'a' must be a number in [0, 1e+09]"),
        ([-1, 0.4, "x"], "its trials -1 must be a number in [0, 1e+09]"),
        ([None, None, "x"], "its trials None must be a number"),
        ([1e300, 0.4, "x"], "marks[0]=[1e+300, 0.4, 'x'] is invalid: its trials 1e+300 must be a number in [0, 1e+09]"),
        ([1, float("nan"), "x"], "its value nan must be null (a bound on the trials) or a number in [-1e+09, 1e+09]"),
        ([1, -1e300, "x"], "its value -1e+300 must be null"),
        ([1, 0.4, "x" * 5000], "its text must be a string of at most 200 characters, got 5,000 characters"),
    ],
)
def test_bad_marks_are_refused_in_one_line_naming_the_entry(mark, fragment):
    with pytest.raises(ValueError) as error:
        check_marks([mark])
    message = str(error.value)
    assert fragment in message and "\n" not in message and len(message) < 300, message


def test_marks_at_the_bounds_are_taken_and_the_second_bad_one_is_named():
    """The control: the bounds themselves pass; a bad entry after good ones is named by its own index."""
    top = "x" * 200
    assert check_marks([[1e9, -1e9, top], [0, None, ""]]) == [(1e9, -1e9, top), (0.0, None, "")]
    with pytest.raises(ValueError, match=r"^marks\[1\]=\[1, 2\] is invalid"):
        check_marks([[1, 0.5, "fine"], [1, 2]])
    with pytest.raises(ValueError, match=r"^marks=5 is invalid: must be a list of \[trials, value or null, 'text'\]"):
        check_marks(5)


def test_default_labels_tell_runs_with_the_same_name_apart(tmp_path):
    a = write_curve(tmp_path / "sweep_a" / "0" / "learning_curve.csv", [1, 1], [0.1, 0.2]).parent
    b = write_curve(tmp_path / "sweep_b" / "0" / "learning_curve.csv", [1, 1], [0.3, 0.4]).parent
    labels = [line.get_label() for line in draw_runs([a, b]).get_lines()]
    assert labels == ["sweep_a/0", "sweep_b/0"]


@pytest.mark.parametrize(
    ("labels", "message"),
    [(["one"], "one label per run"), (["same", "same"], "its own label")],
)
def test_bad_labels_are_refused(runs, labels, message):
    with pytest.raises(ValueError, match=message):
        draw_runs([runs["VQQL"], runs["IT-VQQL"]], labels=labels)


def test_cli_draws_the_runs(runs, tmp_path):
    run_list = ",".join(str(p) for p in runs.values())
    command = [
        sys.executable,
        "-m",
        "pedrl.plot",
        f"runs=[{run_list}]",
        "labels=[VQQL,IT-VQQL,IN-VQQL]",
        "smooth=3",
        f"hydra.run.dir={tmp_path}",
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "learning_curves.png").is_file()
    assert f"wrote {tmp_path / 'learning_curves.png'}" in done.stdout


def test_cli_takes_one_run_without_brackets(runs, tmp_path):
    command = [sys.executable, "-m", "pedrl.plot", f"runs={runs['VQQL']}", f"hydra.run.dir={tmp_path}"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "learning_curves.png").is_file()


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("runs=[]", "pedrl-plot: error: runs=[] is invalid"),
        ("runs=[/no/such/run]", "pedrl-plot: error: no learning curve at '/no/such/run'"),
        ("smooth=0", "pedrl-plot: error: smooth=0 is invalid"),
        ("labels=[a,b]", "pedrl-plot: error: labels=['a', 'b'] is invalid"),
    ],
)
def test_cli_reports_bad_input_in_one_line(runs, tmp_path, override, message):
    command = [sys.executable, "-m", "pedrl.plot", f"runs=[{runs['VQQL']}]", override, f"hydra.run.dir={tmp_path}"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(message), done.stderr


# ---------------------------------------------------------------------- refused input (the bad-input catalogue)
@pytest.fixture
def read_only_dir(tmp_path) -> Iterator[Path]:
    yield from read_only_folder(tmp_path)


def _foreign_csv(run: Path) -> None:
    (run / "learning_curve.csv").write_text("phase,global_trial,speed_mean\n1,2,3\n")


def _header_only(run: Path) -> None:
    (run / "learning_curve.csv").write_text(",".join(CURVE_COLUMNS) + "\n")


def _malformed_row(run: Path) -> None:
    path = run / "learning_curve.csv"
    path.write_text(path.read_text() + "x" * 5 + "\n")


PLOT_CASES: list[tuple[str, str, Callable[[Path], None] | None, tuple[str, ...]]] = [
    ("no_runs", "runs=[]", None, ("runs=[]", "one or more run directories")),
    ("absent_run", "runs=[{tmp}/absent]", None, ("absent", "expected a run directory")),
    ("smooth_0", "smooth=0", None, ("smooth=0", "integer >= 1")),
    ("smooth_abc", "smooth=abc", None, ("smooth='abc'", "integer >= 1")),
    ("metric_foo", "metric=foo", None, ("metric='foo'", "one of", "success_rate")),
    ("two_labels", "labels=[a,b]", None, ("labels=", "one label per run")),
    ("layout_foo", "layout=foo", None, ("layout='foo'", "one of whole, phases")),
    ("marks_5", "layout=phases marks=5", None, ("marks=5 is invalid", "a list of [trials, value or null, 'text']")),
    ("marks_entry_5", "marks=[5]", None, ("marks[0]=5 is invalid", "[trials, value or null, 'text']")),
    ("marks_1e300", "layout=phases marks=[[1e300,0.4,end]]", None,
     ("marks[0]=[1e+300, 0.4, 'end'] is invalid", "its trials 1e+300 must be a number in [0, 1e+09]")),
    ("marks_long_text", "marks=[[5,0.4,'" + "x" * 5000 + "']]", None,
     ("marks[0]=[5, 0.4, 'xxx", "at most 200 characters, got 5,000 characters")),
    ("same_labels", "runs=[{run},{run}] labels=[a,a]", None, ("labels=['a', 'a']", "its own label")),
    ("binary_csv", "", binary_curve, ("learning_curve.csv", "not a CSV text file")),
    ("foreign_csv", "", _foreign_csv, ("metric='success_rate' is not in", "learning_curve.csv", "one of speed")),
    ("header_only", "", _header_only, ("learning_curve.csv", "has no rows")),
    ("malformed_row", "", _malformed_row, ("learning_curve.csv", "malformed")),
    (
        "output_under_a_file",
        "output={tmp}/figure.png/inside.png",
        lambda run: (run.parent / "figure.png").write_text(""),
        ("figure.png",),
    ),
]  # fmt: skip


@pytest.mark.parametrize(
    ("overrides", "damage", "fragments"), catalogue(PLOT_CASES, {"no_runs", "binary_csv", "marks_5"}, named=True)
)
def test_plot_refuses(overrides, damage, fragments, tmp_path, capsys):
    run = tmp_path / "a_run"
    write_small_curve(run / "learning_curve.csv")
    if damage is not None:
        damage(run)
    run_dir = tmp_path / "plots"
    args = [f"runs=[{run}]", *overrides.format(tmp=tmp_path, run=run).split(), f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(pedrl.plot, args, capsys)
    assert_refused(outcome, "pedrl-plot", fragments)
    assert_nothing_computed(run_dir)


def test_plot_into_a_read_only_folder_names_the_path(tmp_path, read_only_dir, capsys):
    run = write_small_curve(tmp_path / "a_run" / "learning_curve.csv").parent
    output = read_only_dir / "sub" / "curves.png"
    args = [f"runs=[{run}]", f"output={output}", f"hydra.run.dir={tmp_path / 'plots'}"]
    outcome = run_hydra_main(pedrl.plot, args, capsys)
    assert_refused(outcome, "pedrl-plot", (str(read_only_dir / "sub"),))
