"""``pedrl-sweep MULTIRUN_DIR``: one table and one figure from the jobs of a Hydra sweep of ``pedrl-train``.

After ``pedrl-train experiment=k_sweep`` (or any ``--multirun``), every job directory of the sweep holds
``summary.json`` (written by :mod:`pedrl.train`) and ``.hydra/overrides.yaml`` + ``.hydra/config.yaml``.
:func:`summarise_sweep` reads them all and writes, into the sweep directory,

- ``sweep_summary.csv``: one row per finished job: its overrides, the swept parameter, the final figures;
- ``sweep_k.png``: final success rate against the swept parameter (a log2 axis where its values are powers of two,
  as K), with ±1 standard deviation over the learning processes as error bars.

The swept parameter is ``--parameter`` if given, else the key the sweep varies (:func:`swept_parameter`): the one
override key set in every job with a value that differs between jobs (``seed`` aside); of several such keys, the one
whose values are all numbers (``algo=vqql,it_vqql vq.num_prototypes=512,1024``: K); more than one numeric key is
refused in one line asking for ``--parameter``; no varying key (one job, or seeds only): ``vq.num_prototypes``.

Jobs that differ in other swept overrides (``algo=vqql,it_vqql``) are drawn as separate series; jobs that differ
only in ``seed`` are pooled into one point (mean over jobs, standard deviation over all their processes).
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

from matplotlib.axes import Axes
from matplotlib.figure import Figure
from omegaconf import OmegaConf

from pedrl.learning_curves import room_rows

SUMMARY_CSV: Final = "sweep_summary.csv"
FIGURE: Final = "sweep_k.png"
DEFAULT_PARAMETER: Final = "vq.num_prototypes"
"""The x axis of a sweep that varies no key (one job, or seeds only): K."""
POOLED_OVERRIDES: Final = ("seed",)
"""Override keys whose jobs are pooled into one point of the figure (repetitions, not settings)."""
LAST_TRIALS: Final = 10
"""``success_rate_last_trials`` averages the success rate of this many last learning trials (less noisy than the
last trial alone)."""
FINAL_METRICS: Final = ("success_rate", "episodic_return", "crashes_agent", "crashes_wall", "mean_speed")
COLUMNS: Final = (
    "job",
    "overrides",
    "series",
    "parameter",
    "value",
    "algo",
    *(f"{m}_{s}" for m in FINAL_METRICS for s in ("mean", "std")),
    "success_rate_last_trials",
    "wall_time_s",
    "phases",
    "gather_success_rate_first",
    "gather_success_rate_last",
    "prototypes_last",
    "distortion_last",
)


def summarise_sweep(
    sweep_dir: str | Path,
    *,
    parameter: str | None = None,
    write: bool = True,
) -> list[dict[str, Any]]:
    """Read every finished job of a sweep; write ``sweep_summary.csv`` and ``sweep_k.png`` into ``sweep_dir``.

    Args:
        sweep_dir: the sweep directory (``hydra.sweep.dir``), whose sub-directories are the jobs.
        parameter: the dotted config key on the x axis; its value is read from each job's resolved config
            (``.hydra/config.yaml``), so it need not be among the job's overrides. None: the key the sweep varies
            (:func:`swept_parameter`).
        write: write the CSV and the figure (False: only return the rows).

    Returns:
        One row per job with a ``summary.json``, sorted by series then by ``value``; keys are :data:`COLUMNS`
        (``success_rate_mean``/``_std`` are the fraction of agents reaching the door in the last learning trial,
        mean and standard deviation over the job's learning processes; ``wall_time_s`` in seconds).

    Raises:
        ValueError: ``sweep_dir`` is not a directory, holds no finished job, a job lacks ``parameter``, the sweep
            varies several numeric keys and ``parameter`` is None, or jobs differ in which keys they override
            (beyond ``parameter`` and the pooled ``seed``): they come from different sweeps, and their series could
            not be named.
    """
    sweep_dir = Path(sweep_dir)
    if sweep_dir.exists() and not sweep_dir.is_dir():
        raise ValueError(f"sweep directory {str(sweep_dir)!r} is a file: give the folder of a pedrl-train --multirun")
    if not sweep_dir.is_dir():
        raise ValueError(f"sweep directory {str(sweep_dir)!r} does not exist")
    jobs = sorted((p.parent for p in sweep_dir.glob("*/summary.json")), key=_job_order)
    if not jobs:
        raise ValueError(
            f"no finished job in {str(sweep_dir)!r}: expected <job>/summary.json written by pedrl-train --multirun"
        )
    job_overrides = {job: _read_overrides(job) for job in jobs}
    varying = _varying_keys(job_overrides.values())
    if parameter is None:
        parameter, _ = swept_parameter(job_overrides.values())
    _check_series_keys(job_overrides, [k for k in varying if k != parameter and k not in POOLED_OVERRIDES])
    rows = [_job_row(job, job_overrides[job], varying, parameter) for job in jobs]
    rows.sort(key=lambda row: (row["series"], _sort_value(row["value"]), row["job"]))
    if write:
        _write_csv(rows, sweep_dir / SUMMARY_CSV)
        axes = plot_sweep(rows, parameter=parameter)
        axes.figure.savefig(sweep_dir / FIGURE, dpi=120)
    return rows


def swept_parameter(all_overrides: Iterable[Mapping[str, str]]) -> tuple[str, str]:
    """The key a sweep varies, the x axis when ``--parameter`` is not given, and why it was chosen (for the console).

    The candidates are the override keys set in every job whose value differs between jobs, ``seed`` (pooled)
    aside: one candidate is the parameter; of several, the one whose values all read as numbers (the others, such
    as ``algo``, become series); none: :data:`DEFAULT_PARAMETER`.

    Args:
        all_overrides: each job's ``key -> value`` overrides (``.hydra/overrides.yaml``).

    Raises:
        ValueError: one line, when several candidates have numeric values: the x axis is ambiguous.
    """
    all_overrides = list(all_overrides)
    candidates = [
        key
        for key in _varying_keys(all_overrides)
        if key not in POOLED_OVERRIDES and all(key in overrides for overrides in all_overrides)
    ]
    if not candidates:
        return DEFAULT_PARAMETER, f"no key varies between the jobs: {DEFAULT_PARAMETER} by default"
    if len(candidates) == 1:
        return candidates[0], "the key the sweep varies"
    numeric = [key for key in candidates if all(_is_number(_parse_scalar(o[key])) for o in all_overrides)]
    if len(numeric) == 1:
        others = ", ".join(key for key in candidates if key != numeric[0])
        return numeric[0], f"the numeric key the sweep varies; {others}: series"
    raise ValueError(
        f"the sweep varies {', '.join(numeric or candidates)}: give --parameter KEY, the key on the x axis (the other"
        " varying keys become series)"
    )


def plot_sweep(rows: Sequence[dict[str, Any]], *, parameter: str = DEFAULT_PARAMETER, axes: Axes | None = None) -> Axes:
    """Final success rate against ``parameter``, one series per setting, ±1 std error bars; returns the axes.

    A numeric parameter whose values are all powers of two (K) gets a log2 x axis with one tick per value.
    """
    if axes is None:
        axes = Figure(figsize=(6.5, 4.5), layout="constrained").subplots()
    points = pool_rows(rows)
    values = sorted({p["value"] for p in points}, key=_sort_value)
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)
    series_names = sorted({p["series"] for p in points})
    for series in series_names:
        own = [p for p in points if p["series"] == series]
        xs = [p["value"] if numeric else values.index(p["value"]) for p in own]
        axes.errorbar(
            xs,
            [p["success_rate_mean"] for p in own],
            yerr=[p["success_rate_std"] for p in own],
            marker="o",
            capsize=4,
            label=series or None,
        )
    if numeric and values and all(v > 0 and float(math.log2(v)).is_integer() for v in values):
        axes.set_xscale("log", base=2)
        axes.set_xticks(values, [str(v) for v in values])
        axes.minorticks_off()
    elif not numeric:
        axes.set_xticks(range(len(values)), [str(v) for v in values])
    axes.set_xlabel("K (prototypes)" if parameter == DEFAULT_PARAMETER else parameter)
    axes.set_ylabel("final success rate (fraction reaching the door)")
    axes.set_ylim(bottom=0.0)
    axes.grid(alpha=0.3)
    if any(series_names):
        axes.legend()
    return axes


def pool_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One point per (series, value): jobs that differ only in a pooled override (``seed``) are combined.

    The point's mean is the mean of the jobs' means; its std is the standard deviation over all their learning
    processes (equal process counts assumed): ``sqrt(mean(std_j^2) + var(mean_j))``.
    """
    groups: dict[tuple[str, Any], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["series"], row["value"]), []).append(row)
    points = []
    for (series, value), members in groups.items():
        means = [m["success_rate_mean"] for m in members]
        mean = sum(means) / len(means)
        variance = sum(m["success_rate_std"] ** 2 for m in members) / len(members)
        variance += sum((x - mean) ** 2 for x in means) / len(means)
        points.append(
            {"series": series, "value": value, "success_rate_mean": mean, "success_rate_std": math.sqrt(variance)}
        )
    points.sort(key=lambda p: (p["series"], _sort_value(p["value"])))
    return points


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """A fixed-width console table of the sweep: value, success (last trial mean ± std over processes, and the
    mean of the last trials), crashes per agent, mean speed, wall time."""
    header = (
        "series",
        "value",
        "success (last trial)",
        f"success (last {LAST_TRIALS})",
        "crashes agent",
        "crashes wall",
        "speed (m/s)",
        "wall time (s)",
        "job",
    )
    lines = [
        (
            row["series"],
            str(row["value"]),
            f"{row['success_rate_mean']:.3f} ± {row['success_rate_std']:.3f}",
            _format_number(row["success_rate_last_trials"], 3),
            f"{row['crashes_agent_mean']:.2f}",
            f"{row['crashes_wall_mean']:.2f}",
            f"{row['mean_speed_mean']:.2f}",
            f"{row['wall_time_s']:.1f}",
            row["job"],
        )
        for row in rows
    ]
    if not any(row["series"] for row in rows):
        header, lines = header[1:], [line[1:] for line in lines]
    widths = [max(len(str(c)) for c in column) for column in zip(header, *lines, strict=True)]
    return "\n".join("  ".join(f"{c:<{w}}" for c, w in zip(line, widths, strict=True)) for line in [header, *lines])


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m pedrl.sweep MULTIRUN_DIR``: print the table, write the CSV and the figure.

    A missing or unfinished sweep directory ends in one line on stderr and exit code 2.
    """
    from pedrl.cli import run_reporting_errors
    from pedrl.common.commands import OneLineParser

    parser = OneLineParser(
        prog="pedrl-sweep",
        description="Summarise a pedrl-train sweep: sweep_summary.csv and sweep_k.png in the sweep directory.",
    )
    parser.add_argument("sweep_dir", help="the sweep directory (hydra.sweep.dir), e.g. multirun/k_sweep/<date>")
    parser.add_argument(
        "--parameter",
        default=None,
        help="dotted config key on the x axis (default: the key whose value differs between the jobs, seed aside;"
        f" of several, the numeric one; none: {DEFAULT_PARAMETER})",
    )
    args = parser.parse_args(argv)
    rows = run_reporting_errors("pedrl-sweep", lambda: summarise_sweep(args.sweep_dir, parameter=args.parameter))
    print(format_table(rows))
    sweep_dir = Path(args.sweep_dir)
    if args.parameter is None:
        reason = swept_parameter(_read_overrides(sweep_dir / row["job"]) for row in rows)[1]
        print(f"x axis: {rows[0]['parameter']} ({reason})")
    print(f"wrote {sweep_dir / SUMMARY_CSV} and {sweep_dir / FIGURE}")


# ---------------------------------------------------------------------- reading one job
def _job_row(job: Path, overrides: dict[str, str], varying: list[str], parameter: str) -> dict[str, Any]:
    summary_path = job / "summary.json"
    try:
        summary = json.loads(summary_path.read_text())
        final = summary["final"]
        row: dict[str, Any] = {
            "job": job.name,
            "overrides": " ".join(f"{k}={v}" for k, v in overrides.items()),
            "series": " ".join(f"{k}={overrides[k]}" for k in varying if k != parameter and k not in POOLED_OVERRIDES),
            "parameter": parameter,
            "value": _parameter_value(job, overrides, parameter),
            "algo": summary.get("algo", ""),
            **{f"{m}_{s}": float(final[f"{m}_{s}"]) for m in FINAL_METRICS for s in ("mean", "std")},
            "wall_time_s": float(summary["wall_time_s"]),
        }
    except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as err:
        raise ValueError(f"{str(summary_path)!r} is not a summary written by pedrl-train ({err!r})") from None
    phases = summary.get("phases") or [{}]
    row.update(
        success_rate_last_trials=_last_trials_success(job / "learning_curve.csv"),
        phases=len(summary.get("phases") or []),
        gather_success_rate_first=phases[0].get("gather_success_rate", ""),
        gather_success_rate_last=phases[-1].get("gather_success_rate", ""),
        prototypes_last=phases[-1].get("prototypes", ""),
        distortion_last=phases[-1].get("distortion", ""),
    )
    return row


def _last_trials_success(path: Path) -> float | str:
    """Mean success rate of the last :data:`LAST_TRIALS` rows of ``learning_curve.csv`` ('' without the file); of a
    run trained across scenarios, the last rows of its own room (the room of its last row)."""
    if not path.is_file():
        return ""
    with open(path, newline="") as handle:
        rows = room_rows(list(csv.DictReader(handle)))[-LAST_TRIALS:]
    try:
        return sum(float(r["success_rate_mean"]) for r in rows) / len(rows) if rows else ""
    except (KeyError, ValueError):
        return ""


def _read_overrides(job: Path) -> dict[str, str]:
    """``key -> value`` of the job's command-line and sweep overrides (``.hydra/overrides.yaml``), in order."""
    path = job / ".hydra" / "overrides.yaml"
    if not path.is_file():
        return {}
    overrides = {}
    for item in OmegaConf.to_container(_load_yaml(path)) or []:
        key, _, value = str(item).partition("=")
        overrides[key.lstrip("+~")] = value
    return overrides


def _parameter_value(job: Path, overrides: dict[str, str], parameter: str) -> Any:
    config_path = job / ".hydra" / "config.yaml"
    if config_path.is_file():
        value = OmegaConf.select(_load_yaml(config_path), parameter, default=None)
        if OmegaConf.is_config(value):
            return str(OmegaConf.to_container(value))  # a list or group: hashable and readable in the table
        if value is not None:
            return value
    if parameter in overrides:
        return _parse_scalar(overrides[parameter])
    raise ValueError(f"job {str(job)!r} has no value for parameter={parameter!r} (in its config or overrides)")


def _load_yaml(path: Path) -> Any:
    """A job's ``.hydra/*.yaml``; an unreadable one is a one-line ``ValueError`` naming it."""
    from omegaconf.errors import OmegaConfBaseException
    from yaml import YAMLError

    try:
        return OmegaConf.load(path)
    except (UnicodeDecodeError, YAMLError, OmegaConfBaseException) as err:
        reason = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise ValueError(f"{str(path)!r} is not a config written by Hydra ({reason})") from None


def _check_series_keys(job_overrides: dict[Path, dict[str, str]], keys: Sequence[str]) -> None:
    """Refuse, in one line naming the key and the jobs without it, jobs that do not all override ``keys`` (the keys
    that name a series): ``algo`` in some jobs and not in others means jobs of different sweeps in one folder."""
    for key in keys:
        lacking = [job.name for job, overrides in job_overrides.items() if key not in overrides]
        if lacking:
            having = [job.name for job, overrides in job_overrides.items() if key in overrides]
            raise ValueError(
                f"override {key!r} is set in job{'s' if len(having) > 1 else ''} {_some(having)} but not in "
                f"job{'s' if len(lacking) > 1 else ''} {_some(lacking)}: every job of a sweep overrides the same keys;"
                " summarise the jobs of one --multirun (or move the others to another folder)"
            )


def _some(names: Sequence[str], shown: int = 5) -> str:
    """``0, 1, 2`` or, for many names, ``0, 1, 2, 3, 4, ... (12 in all)``."""
    return ", ".join(names[:shown]) + (f", ... ({len(names)} in all)" if len(names) > shown else "")


def _varying_keys(all_overrides: Any) -> list[str]:
    """Override keys whose value is not the same in every job, in first-seen order."""
    all_overrides = list(all_overrides)
    keys: list[str] = []
    for overrides in all_overrides:
        keys.extend(k for k in overrides if k not in keys)
    return [k for k in keys if len({o.get(k) for o in all_overrides}) > 1]


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _format_number(value: Any, digits: int) -> str:
    return f"{value:.{digits}f}" if isinstance(value, int | float) else str(value)


def _parse_scalar(text: str) -> Any:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _job_order(job: Path) -> tuple[int, int | str]:
    return (0, int(job.name)) if job.name.isdigit() else (1, job.name)


def _sort_value(value: Any) -> tuple[int, Any]:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return (0, value)
    return (1, str(value))


def _write_csv(rows: Sequence[dict[str, Any]], path: Path) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


if __name__ == "__main__":
    main()
