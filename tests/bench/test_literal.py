"""The ``literal`` section of the benchmark times the searches on the same states and finds the same ids (its timings
are measurements, not asserted)."""

import pytest

from pedrl._numba import numba_available
from pedrl.bench.__main__ import main


@pytest.mark.slow  # about 33 s on a cold numba cache; tests/vq/test_pruned.py checks the same ids in make test
@pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")
def test_quick_literal_times_both_searches_and_finds_the_same_ids(tmp_path):
    report = main(["--quick", "--only", "literal", "--output", str(tmp_path / "bench.json")])
    times = report["literal_us_per_state"]
    assert all(times[name] > 0 for name in ("scan", "pruned", "matmul_room", "matmul_decision"))
    assert report["literal_speedup"] == pytest.approx(times["scan"] / times["pruned"])
    assert report["literal_same_ids"] is True
    assert 0.0 <= report["literal_matmul_other_ids"] <= 0.01  # the expanded form's float32 rounding, at near-ties
    assert report["literal_work"]["leaf_pairs"] == report["literal_config"]["prototypes"] // 32
