"""The ``eval`` section of the benchmark runs and reports both paths (its figures are measurements, not asserted)."""

import pytest

from pedrl._numba import numba_available
from pedrl.bench.__main__ import main


@pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")
def test_quick_eval_writes_both_rates_and_their_ratio(tmp_path):
    report = main(["--quick", "--only", "eval", "--output", str(tmp_path / "bench.json")])
    (row,) = report["eval"].values()
    assert row["torch_agent_decisions_per_s"] > 0 and row["fused_agent_decisions_per_s"] > 0
    assert row["ratio"] == pytest.approx(row["fused_agent_decisions_per_s"] / row["torch_agent_decisions_per_s"])
    assert (tmp_path / "bench.json").exists()


def test_an_unknown_section_is_refused_in_one_line(capsys):
    with pytest.raises(SystemExit):
        main(["--only", "evaluation"])
    assert "unknown sections ['evaluation']: allowed sim, kmeans, e2e, eval" in capsys.readouterr().err
