"""``python -m pedrl.bench --only factored``: the plain and factored rows of the main job's room (a smoke run, no
timed targets)."""

import json

from pedrl.bench.__main__ import main


def test_quick_factored_section_writes_both_tables(tmp_path):
    output = tmp_path / "bench.json"
    main(["--quick", "--only", "factored", "--output", str(output)])
    report = json.loads(output.read_text())
    plain, factored = report["factored"]
    assert (plain["table"], plain["slots"]) == ("plain", 1)
    assert factored["table"] == "factored" and factored["slots"] == 1 + 7 + 2
    assert factored["states"] <= 256 + 256 + 32
    assert min(plain["agent_decisions_per_s"], factored["agent_decisions_per_s"]) > 0
    assert report["factored_ratio"] == factored["agent_decisions_per_s"] / plain["agent_decisions_per_s"]
