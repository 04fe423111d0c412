"""pedrl.sweep (table and figure of a sweep) and the Hydra launcher configs (joblib, submitit local and slurm);
and the sweep part of the bad-input catalogue (:mod:`tests.refusals`)."""

import csv
import json
import math
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import pedrl.sweep
from pedrl.cli import CONFIG_DIR
from pedrl.sweep import FIGURE, SUMMARY_CSV, main, plot_sweep, pool_rows, summarise_sweep, swept_parameter
from tests.refusals import assert_refused, make_plain_job, run_sweep_main


def make_job(sweep_dir, name, *, overrides, success, std=0.05, num_prototypes=None, curve=None):
    """A job directory as pedrl-train --multirun leaves it: summary.json and .hydra/{overrides,config}.yaml."""
    job = sweep_dir / name
    (job / ".hydra").mkdir(parents=True)
    OmegaConf.save(OmegaConf.create(list(overrides)), job / ".hydra" / "overrides.yaml")
    if num_prototypes is not None:
        OmegaConf.save(
            OmegaConf.create({"vq": {"num_prototypes": num_prototypes}, "seed": 0}), job / ".hydra" / "config.yaml"
        )
    final = {
        f"{m}_{s}": 0.0
        for m in ("success_rate", "episodic_return", "crashes_agent", "crashes_wall", "mean_speed")
        for s in ("mean", "std")
    }
    final.update(success_rate_mean=success, success_rate_std=std, td_error_mean=1.0, td_error_std=0.0)
    phases = [{"phase": 1, "gather_success_rate": 0.07, "prototypes": num_prototypes or 0, "distortion": 3.0}]
    summary = {"algo": "vqql", "final": final, "wall_time_s": 12.5, "phases": phases, "checkpoint": "x"}
    (job / "summary.json").write_text(json.dumps(summary))
    if curve is not None:
        with open(job / "learning_curve.csv", "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["phase", "success_rate_mean"])
            writer.writerows([1, value] for value in curve)
    return job


@pytest.fixture
def k_sweep_dir(tmp_path):
    """Six jobs over K, numbered as Hydra numbers them (0..5; 10 sorts after 9, not after 1)."""
    for number, k in enumerate((512, 1024, 2048, 4096, 8192, 16384)):
        make_job(
            tmp_path,
            str(number),
            overrides=[f"vq.num_prototypes={k}", "experiment=k_sweep"],
            success=0.1 * (number + 1),
            num_prototypes=k,
            curve=[0.0] * 5 + [0.1 * number] * 10,
        )
    return tmp_path


def test_summary_rows_csv_and_figure(k_sweep_dir):
    rows = summarise_sweep(k_sweep_dir)
    assert [r["value"] for r in rows] == [512, 1024, 2048, 4096, 8192, 16384]
    assert [r["success_rate_mean"] for r in rows] == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    assert rows[2]["success_rate_last_trials"] == pytest.approx(0.2)  # the mean of the last 10 trials
    assert {r["series"] for r in rows} == {""}  # only K varies
    assert rows[0]["overrides"] == "vq.num_prototypes=512 experiment=k_sweep"
    with open(k_sweep_dir / SUMMARY_CSV, newline="") as handle:
        written = list(csv.DictReader(handle))
    assert [int(r["value"]) for r in written] == [512, 1024, 2048, 4096, 8192, 16384]
    assert float(written[-1]["success_rate_mean"]) == pytest.approx(0.6)
    assert (k_sweep_dir / FIGURE).stat().st_size > 10_000


def test_figure_has_a_log2_axis_and_error_bars(k_sweep_dir):
    rows = summarise_sweep(k_sweep_dir, write=False)
    axes = plot_sweep(rows)
    assert axes.get_xscale() == "log"
    assert [t.get_text() for t in axes.get_xticklabels()] == ["512", "1024", "2048", "4096", "8192", "16384"]
    (errorbar,) = axes.containers
    line, _, (bars,) = errorbar.lines
    assert list(line.get_xdata()) == [512, 1024, 2048, 4096, 8192, 16384]
    low, high = bars.get_segments()[0][:, 1]
    assert (low, high) == pytest.approx((0.05, 0.15))  # ±1 std over the processes


def test_jobs_of_other_settings_are_series_and_seeds_are_pooled(tmp_path):
    for number, (algo, k, seed, success) in enumerate(
        [("vqql", 512, 0, 0.2), ("vqql", 512, 1, 0.4), ("it_vqql", 512, 0, 0.5), ("it_vqql", 1024, 0, 0.7)]
    ):
        overrides = [f"algo={algo}", f"vq.num_prototypes={k}", f"seed={seed}"]
        make_job(tmp_path, str(number), overrides=overrides, success=success, std=0.1)
    rows = summarise_sweep(tmp_path)  # K from the overrides: these jobs have no .hydra/config.yaml
    assert [(r["series"], r["value"]) for r in rows] == [
        ("algo=it_vqql", 512),
        ("algo=it_vqql", 1024),
        ("algo=vqql", 512),
        ("algo=vqql", 512),
    ]
    points = pool_rows(rows)
    vqql = [p for p in points if p["series"] == "algo=vqql"]
    assert len(vqql) == 1 and vqql[0]["success_rate_mean"] == pytest.approx(0.3)
    assert vqql[0]["success_rate_std"] == pytest.approx(math.sqrt(0.1**2 + 0.1**2))
    legend = plot_sweep(rows).get_legend()
    assert sorted(t.get_text() for t in legend.get_texts()) == ["algo=it_vqql", "algo=vqql"]


def _alpha_sweep(sweep_dir, alphas=(0.1, 0.2, 0.4), *, extra=()):
    """Jobs of ``pedrl-train --multirun algo.alpha=...`` at K = 512 (set on the command line, the same in every job)."""
    for number, alpha in enumerate(alphas):
        overrides = [
            "experiment=quick_vqql",
            "vq.num_prototypes=512",
            f"algo.alpha={alpha}",
            *extra[number : number + 1],
        ]
        make_job(sweep_dir, str(number), overrides=overrides, success=alpha, num_prototypes=512)
    return sweep_dir


def test_the_x_axis_is_the_key_the_sweep_varies(tmp_path, capsys):
    """A sweep of algo.alpha was plotted against K (one point at 512) unless --parameter was given; now against
    the key whose value differs between the jobs, and the console says so. The control: --parameter still rules."""
    sweep = _alpha_sweep(tmp_path)
    main([str(sweep)])
    out = capsys.readouterr().out
    assert "x axis: algo.alpha (the key the sweep varies)" in out
    with open(sweep / SUMMARY_CSV, newline="") as handle:
        written = list(csv.DictReader(handle))
    assert [(r["parameter"], float(r["value"])) for r in written] == [("algo.alpha", a) for a in (0.1, 0.2, 0.4)]
    rows = summarise_sweep(sweep, parameter="vq.num_prototypes", write=False)
    assert {(r["parameter"], r["value"]) for r in rows} == {("vq.num_prototypes", 512)}
    main([str(sweep), "--parameter", "vq.num_prototypes"])
    assert "x axis:" not in capsys.readouterr().out


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ([{"algo.alpha": "0.1"}, {"algo.alpha": "0.2"}], ("algo.alpha", "the key the sweep varies")),
        ([{"algo": "vqql"}, {"algo": "it_vqql"}], ("algo", "the key the sweep varies")),
        (
            [{"algo": "vqql", "vq.num_prototypes": "512"}, {"algo": "it_vqql", "vq.num_prototypes": "1024"}],
            ("vq.num_prototypes", "the numeric key the sweep varies; algo: series"),
        ),
        ([{"seed": "0"}, {"seed": "1"}], ("vq.num_prototypes", "no key varies between the jobs")),
        ([{"algo.alpha": "0.1"}], ("vq.num_prototypes", "no key varies between the jobs")),
        ([{"algo": "vqql"}, {"algo": "vqql", "algo.alpha": "0.2"}], ("vq.num_prototypes", "no key varies")),
    ],
)
def test_swept_parameter_picks_one_key_deterministically(overrides, expected):
    key, reason = swept_parameter(overrides)
    assert key == expected[0] and expected[1] in reason, (key, reason)
    assert swept_parameter(reversed(overrides))[0] == key  # whatever the jobs' order


def test_a_sweep_of_two_numeric_keys_asks_for_the_parameter(tmp_path, capsys):
    """algo.alpha and algo.gamma both vary: no guess, one line naming both; --parameter settles it (the control)."""
    sweep = _alpha_sweep(tmp_path, extra=["algo.gamma=0.9", "algo.gamma=0.95", "algo.gamma=0.99"])
    outcome = run_sweep_main([str(sweep)], capsys)
    assert_refused(outcome, "pedrl-sweep", ("the sweep varies algo.alpha, algo.gamma", "give --parameter KEY"))
    assert not (sweep / SUMMARY_CSV).exists()
    rows = summarise_sweep(sweep, parameter="algo.gamma", write=False)
    assert [(r["series"], r["value"]) for r in rows] == [
        ("algo.alpha=0.1", 0.9), ("algo.alpha=0.2", 0.95), ("algo.alpha=0.4", 0.99)
    ]  # fmt: skip


def test_unfinished_jobs_are_left_out(k_sweep_dir):
    (k_sweep_dir / "6" / ".hydra").mkdir(parents=True)  # a job that crashed before writing summary.json
    assert len(summarise_sweep(k_sweep_dir, write=False)) == 6


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda d: d / "absent", "does not exist"),
        (lambda d: d, "no finished job"),
        (lambda d: _broken_summary(d), "is not a summary written by pedrl-train"),
    ],
)
def test_bad_sweep_directories(tmp_path, make, message):
    with pytest.raises(ValueError, match=message):
        summarise_sweep(make(tmp_path))


def _broken_summary(sweep_dir):
    job = make_job(sweep_dir, "0", overrides=["vq.num_prototypes=512"], success=0.5, num_prototypes=512)
    (job / "summary.json").write_text("{not json")
    return sweep_dir


def test_main_prints_the_table(k_sweep_dir, capsys):
    main([str(k_sweep_dir)])
    out = capsys.readouterr().out
    assert "16384" in out and "0.600 ± 0.050" in out and f"wrote {k_sweep_dir / SUMMARY_CSV}" in out


def test_main_reports_a_missing_directory_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([str(tmp_path / "nothing")])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"pedrl-sweep: error: sweep directory {str(tmp_path / 'nothing')!r} does not exist"
    ]


def test_real_multirun_is_summarised(tmp_path):
    """pedrl-train --multirun with the basic launcher, then python -m pedrl.sweep on its directory."""
    sweep = tmp_path / "sweep"
    command = [
        sys.executable,
        "-m",
        "pedrl.train",
        "--multirun",
        "debug=default",
        "algo.iterations=1",
        "algo.trials=4",
        "logger=none",
        "vq.num_prototypes=16,32",
        f"hydra.sweep.dir={sweep}",
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    done = subprocess.run(
        [sys.executable, "-m", "pedrl.sweep", str(sweep)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    with open(sweep / SUMMARY_CSV, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["value"]) for r in rows] == [16, 32]
    assert [int(r["prototypes_last"]) for r in rows] == [16, 32]
    assert (sweep / FIGURE).is_file()


# ---------------------------------------------------------------------- launchers
def compose_launcher(name):
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        return compose("train", [f"hydra/launcher={name}"], return_hydra_config=True).hydra.launcher


def test_joblib_launcher_composes_and_builds():
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    from hydra.utils import instantiate

    launcher = compose_launcher("parallel")
    assert launcher._target_.endswith("JoblibLauncher")
    assert launcher.n_jobs == 2
    assert type(instantiate(launcher)).__name__ == "JoblibLauncher"


@pytest.mark.parametrize(("name", "target"), [("local", "LocalLauncher"), ("slurm", "SlurmLauncher")])
def test_submitit_launchers_compose(name, target):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    launcher = compose_launcher(name)
    assert launcher._target_.endswith(target)
    assert launcher.timeout_min > 0 and launcher.cpus_per_task >= 1
    if name == "slurm":
        assert "partition" in launcher and launcher.mem_gb > 0


@pytest.mark.slow
def test_submitit_local_launcher_runs_a_sweep(tmp_path):
    """Two debug jobs through submitit's local executor: each runs in its own process and writes its summary."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    sweep = tmp_path / "sweep"
    command = [
        sys.executable,
        "-m",
        "pedrl.train",
        "--multirun",
        "debug=default",
        "hydra/launcher=local",
        "vq.num_prototypes=16,32",
        f"hydra.sweep.dir={sweep}",
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    for job, k in (("0", 16), ("1", 32)):
        summary = json.loads((sweep / job / "summary.json").read_text())
        assert summary["algo"] == "vqql" and summary["phases"][0]["prototypes"] == k
    assert (sweep / ".submitit").is_dir()  # the jobs went through submitit
    assert [r["value"] for r in summarise_sweep(sweep, write=False)] == [16, 32]


# ---------------------------------------------------------------------- refused input (the bad-input catalogue)
def _no_parameter_args(sweep: Path) -> list[str]:
    make_plain_job(sweep)
    return [str(sweep), "--parameter", "algo.alpha"]


def _broken_summary_args(sweep: Path) -> list[str]:
    (make_plain_job(sweep) / "summary.json").write_text("{not json")
    return [str(sweep)]


def _binary_summary_args(sweep: Path) -> list[str]:
    (make_plain_job(sweep) / "summary.json").write_bytes(bytes(range(256)))
    return [str(sweep)]


def _broken_overrides_args(sweep: Path) -> list[str]:
    (make_plain_job(sweep) / ".hydra" / "overrides.yaml").write_text("[unclosed")
    return [str(sweep)]


def _sweep_is_a_file_args(sweep: Path) -> list[str]:
    (sweep / "sweep.txt").write_text("")
    return [str(sweep / "sweep.txt")]


SWEEP_CASES: list[tuple[Callable[[Path], list[str]], tuple[str, ...]]] = [
    (lambda sweep: [str(sweep / "absent")], ("absent", "does not exist")),
    (lambda sweep: [str(sweep)], ("no finished job", "summary.json")),
    (_sweep_is_a_file_args, ("sweep.txt", "is a file")),
    (_no_parameter_args, ("parameter='algo.alpha'", "no value")),
    (_broken_summary_args, ("summary.json", "not a summary written by pedrl-train")),
    (_binary_summary_args, ("summary.json", "not a summary written by pedrl-train")),
    (_broken_overrides_args, ("overrides.yaml", "not a config written by Hydra")),
]


@pytest.mark.parametrize(("make", "fragments"), SWEEP_CASES, ids=[f"case{i}" for i in range(len(SWEEP_CASES))])
def test_sweep_refuses(make, fragments, tmp_path, capsys):
    outcome = run_sweep_main(make(tmp_path), capsys)
    assert_refused(outcome, "pedrl-sweep", fragments)
    assert not (tmp_path / pedrl.sweep.SUMMARY_CSV).exists()


def test_sweep_into_a_read_only_folder_names_the_path(tmp_path, capsys, monkeypatch):
    make_plain_job(tmp_path)

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(tmp_path / pedrl.sweep.SUMMARY_CSV))

    monkeypatch.setattr(pedrl.sweep, "_write_csv", refuse)
    outcome = run_sweep_main([str(tmp_path)], capsys)
    assert_refused(outcome, "pedrl-sweep", (str(tmp_path / pedrl.sweep.SUMMARY_CSV), "Permission denied"))


def test_sweep_of_jobs_with_different_override_keys_names_the_key(tmp_path, capsys):
    """Jobs of two sweeps in one folder (``algo`` overridden in one, not in the other) gave a KeyError blamed on a
    summary.json; now one line naming the key and the jobs that lack it."""
    make_plain_job(tmp_path, "0")
    make_plain_job(tmp_path, "1")
    make_plain_job(tmp_path, "2")
    for name in ("0", "2"):
        OmegaConf.save(
            OmegaConf.create(["vq.num_prototypes=512", "algo=it_vqql"]), tmp_path / name / ".hydra" / "overrides.yaml"
        )
    for args in ([str(tmp_path)], [str(tmp_path), "--parameter", "vq.num_prototypes"]):
        outcome = run_sweep_main(args, capsys)
        assert_refused(outcome, "pedrl-sweep", ("override 'algo'", "set in jobs 0, 2", "not in job 1"))
        assert not (tmp_path / pedrl.sweep.SUMMARY_CSV).exists()


def test_a_mixed_run_is_summarised_by_its_own_room(tmp_path):
    """Rows of a run trained across scenarios alternate rooms; the sweep's success is its own room's (the last
    row's), not a blend of every room's."""
    from pedrl.sweep import _last_trials_success

    path = tmp_path / "learning_curve.csv"
    rows = ["success_rate_mean,room"] + [
        f"{1.0 if t % 2 else 0.0},{'paper_room' if t % 2 else 'corner_20'}" for t in range(40)
    ]
    path.write_text("\n".join(rows) + "\n")
    assert _last_trials_success(path) == pytest.approx(1.0)
    path.write_text("success_rate_mean\n" + "\n".join(["0.5"] * 30) + "\n")  # no room column: every row
    assert _last_trials_success(path) == pytest.approx(0.5)
