"""``python -m pedrl.bench``: the e2e rows and their fraction of the matmul peak (a smoke run, no timed targets)."""

import json

import pytest

from pedrl.bench import e2e
from pedrl.bench.__main__ import main


def test_peak_fraction_is_the_rate_over_the_search_rate_at_the_peak():
    rows = e2e.with_peak_fraction([{"agent_decisions_per_s": 1000.0, "prototypes": 4096}], peak=2 * 4096 * 28 * 4000.0)
    assert rows[0]["fraction_of_matmul_peak"] == pytest.approx(0.25)


def test_matmul_peak_is_a_positive_rate():
    assert e2e.matmul_peak("cpu", size=64, repeats=1) > 0


def test_quick_e2e_writes_its_rows(tmp_path):
    output = tmp_path / "bench.json"
    main(["--quick", "--only", "e2e", "--rooms", "1", "--output", str(output)])
    report = json.loads(output.read_text())
    (row,) = report["e2e"]
    assert row["rooms_per_process"] == 1
    assert row["agent_decisions_per_s"] > 0
    assert 0 < row["fraction_of_matmul_peak"] < 1
    assert report["matmul_peak_flop_per_s"] > 0
