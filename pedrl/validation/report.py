"""Reports of the validation suite: ``validation.json``, ``validation.md`` and figures (PNG and TensorBoard)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any, Final

import numpy as np
from matplotlib.figure import Figure

from pedrl.io.files import replace_atomically
from pedrl.validation.framework import TestResult


def write_reports(
    run_dir: Path,
    results: Mapping[str, Sequence[TestResult]],
    figures: Mapping[str, Mapping[str, Figure]],
    *,
    meta: Mapping[str, Any],
    tensorboard: bool = True,
) -> dict[str, Path]:
    """Write ``validation.json`` (every row of every controller), ``validation.md`` (one column per controller) and
    ``figures/<controller>_<name>.png`` (plus TensorBoard images under ``tb/`` when ``tensorboard``)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    rows = [
        {"controller": name, "status": row.status, **_plain(asdict(row))}
        for name, rows_ in results.items()
        for row in rows_
    ]
    document = {**meta, "tests": rows}
    paths = {"json": run_dir / "validation.json", "md": run_dir / "validation.md"}
    text = json.dumps(document, indent=2, allow_nan=False) + "\n"
    replace_atomically(paths["json"], lambda path: path.write_text(text))
    report = markdown(results, meta=meta)
    replace_atomically(paths["md"], lambda path: path.write_text(report))
    (run_dir / "figures").mkdir(exist_ok=True)
    writer = None
    if tensorboard:
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(str(run_dir / "tb"))
    for controller, named in figures.items():
        for name, figure in named.items():
            figure.tight_layout()
            figure.savefig(run_dir / "figures" / f"{controller}_{name}.png", dpi=110)
            if writer is not None:
                writer.add_figure(f"validation/{controller}/{name}", figure)
    if writer is not None:
        for controller, rows_ in results.items():
            for index, row in enumerate(rows_):
                writer.add_scalar(f"validation/{controller}/passed", float(row.passed), index)
        writer.close()
    return paths


META_NOTES: Final = {
    "verdict": " (the runs are at their published sizes, so every pass and FAIL below counts; False after quick=true,"
    " a smoke run; how many tests passed is the Passed line under the table)",
}
"""What a key of the run's header in ``validation.md`` means, where its value alone would mislead."""


def markdown(results: Mapping[str, Sequence[TestResult]], *, meta: Mapping[str, Any]) -> str:
    """The report as a Markdown table: one row per test, measured value and verdict per controller; the pass count
    leaves out the invariants (a sanity row) and the tests not applicable at the run's body size."""
    controllers = list(results)
    lines = ["# pedrl validation", ""]
    if meta.get("quick"):
        lines += ["**quick: not a verdict** (every run shrunk for a smoke test)", ""]
    lines += [f"- {key}: {_format(value)}{META_NOTES.get(key, '')}" for key, value in meta.items()]
    lines += ["", "| test | " + " | ".join(controllers) + " | reference | source |"]
    lines.append("|---" * (len(controllers) + 3) + "|")
    by_test: dict[str, dict[str, TestResult]] = {}
    for controller, rows in results.items():
        for row in rows:
            by_test.setdefault(row.test, {})[controller] = row
    for test, cells in by_test.items():
        first = next((row for row in cells.values() if row.applicable), next(iter(cells.values())))
        measured = [_cell(cells.get(controller)) for controller in controllers]
        lines.append(f"| {test} | " + " | ".join(measured) + f" | {first.reference} | {first.source} |")
    lines += ["", "Passed: " + ", ".join(f"{c} {pass_count(results[c])}" for c in controllers), ""]
    lines += ["## Details", ""]
    for controller, rows in results.items():
        for row in rows:
            details = ", ".join(f"{key} {_format(value)}" for key, value in row.details.items())
            failed = f" (failed: {'; '.join(row.failed)})" if row.failed else ""
            lines.append(f"- **{controller}, {row.test}**: {row.note or details}{failed}")
    return "\n".join(lines) + "\n"


def pass_count(rows: Sequence[TestResult]) -> str:
    """``"2/5 (1 not applicable)"``: passed over counted applicable tests."""
    counted = [row for row in rows if row.counted]
    applicable = [row for row in counted if row.applicable]
    text = f"{sum(row.passed for row in applicable)}/{len(applicable)}"
    missing = len(counted) - len(applicable)
    return text + (f" ({missing} not applicable)" if missing else "")


CELL_CRITERIA: Final = 2
"""Failed criteria a table cell names beside ``FAIL`` (the Details section and validation.json name them all)."""


def _cell(row: TestResult | None) -> str:
    """A controller's cell: the measured value and the verdict; beside ``FAIL``, the criteria that failed (the value
    shown may meet its own bound while another criterion fails)."""
    if row is None:
        return "not run"
    if not row.applicable:
        return f"{row.reference}: **n/a**"
    cell = f"{_format(row.value)} {row.unit}: **{row.status}**"
    if row.failed:
        more = len(row.failed) - CELL_CRITERIA
        cell += f" ({'; '.join(row.failed[:CELL_CRITERIA])}{f'; {more} more in the details' if more > 0 else ''})"
    return cell


def _format(value: Any) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_format(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(_format(v) for v in value) + "]"
    return str(value)


def _plain(value: Any) -> Any:
    """JSON-safe: numpy scalars become Python ones, infinities and NaN ``None``."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(item) for item in value]
    return value
