"""The ``walk`` section of the benchmark: pedrl's walking layer and JuPedSim walk the same hall, each in its own
process, and its table lands between the page's markers (its figures are measurements, not asserted)."""

import json
import os
import stat

import numpy as np
import pytest

from pedrl._numba import numba_available
from pedrl.bench import walk
from pedrl.bench.__main__ import main

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")
KEYS = {"wall_s", "agent_steps", "agent_steps_per_s", "agent_steps_per_s_per_core", "threads", "agents_left",
        "peak_rss_mib", "peak_growth_mib"}  # fmt: skip


@needs_numba
def test_both_simulators_walk_every_agent_out_of_the_same_hall(tmp_path):
    """20 agents, 15 s: both empty the 7 m hall; the JSON holds every figure, the page keeps what is around its
    markers. The control of "every agent left" is the next test (1 s is too short for that)."""
    pytest.importorskip("jupedsim")
    page = tmp_path / "performance.md"
    start, end = walk.MARKERS
    page.write_text(f"# Performance\n\nabove\n\n{start}\nold table\n{end}\n\nbelow\n")
    output = tmp_path / "bench.json"
    args = ["--quick", "--only", "walk", "--agents", "20", "--sim-time", "15", "--output", str(output)]
    report = main([*args, "--write-docs", str(page)])
    row = report["walk"]["sizes"]["20"]
    pedrl, jupedsim = row["pedrl"], row["jupedsim"]
    assert set(pedrl) >= KEYS and set(jupedsim) >= KEYS, (pedrl, jupedsim)
    assert pedrl["agents_left"] == jupedsim["agents_left"] == 20
    assert pedrl["same_exits_share"] == 1.0  # pedrl's exits are the ones JuPedSim's journeys lead to
    assert pedrl["time_step_s"] == pytest.approx(jupedsim["time_step_s"]) == pytest.approx(walk.TIME_STEP)
    assert pedrl["threads"] == jupedsim["threads"] == 1
    assert row["ratio"] == pytest.approx(pedrl["agent_steps_per_s_per_core"] / jupedsim["agent_steps_per_s_per_core"])
    assert json.loads(output.read_text())["walk"]["settings"]["time_gap_s"] == walk.TIME_GAP
    text = page.read_text()
    assert "old table" not in text and "| 20 | 7.1 m | pedrl |" in text and "| 20 | 7.1 m | JuPedSim |" in text
    assert text.startswith("# Performance\n\nabove\n\n") and text.endswith(f"{end}\n\nbelow\n")


@needs_numba
def test_a_walk_too_short_to_empty_the_hall_leaves_agents_in_it():
    """The control of the test above: in 1 s neither simulator walks all 20 out, so "all 20 left" is measured."""
    pytest.importorskip("jupedsim")
    for simulator in walk.SIMULATORS:
        result = walk.measure(simulator, 20, 1.0)
        assert 0 <= result["agents_left"] < 20, (simulator, result)
        assert 0 < result["agent_steps"] <= 20 * 20, (simulator, result)  # 20 agents, 20 steps of 0.05 s


@needs_numba
def test_without_jupedsim_the_section_runs_pedrl_and_says_why(monkeypatch):
    import pedrl.integrations.jupedsim as integration

    monkeypatch.setattr(integration, "installed", lambda: False)
    result = walk.run(sizes=(10,), sim_time=1.0)["walk"]
    row = result["sizes"]["10"]
    assert row["jupedsim"] == {"skipped": integration.INSTALL_HINT} and row["ratio"] is None
    assert row["pedrl"]["agent_steps"] > 0
    assert f"- JuPedSim at 10 agents: {integration.INSTALL_HINT}" in result["table"]


def _least_gaps(positions: np.ndarray, side: float) -> tuple[float, float]:
    """The least gap between two bodies and between a body and a wall (m)."""
    offsets = positions[:, None, :].astype(np.float64) - positions[None]
    distances = np.sqrt((offsets**2).sum(-1)) + np.eye(len(positions)) * 1e9
    return float(distances.min() - 2 * walk.RADIUS), float(min(positions.min(), side - positions.max()) - walk.RADIUS)


@pytest.mark.parametrize("agents", [10, 999, 1000])
def test_the_start_lattice_keeps_every_body_clear_of_the_others_and_the_walls(agents):
    positions = walk.start_positions(agents)
    side = walk.hall_side(agents)
    bodies, walls = _least_gaps(positions, side)
    assert positions.shape == (agents, 2) and len(np.unique(positions, axis=0)) == agents
    assert bodies >= 2 * walk.CLEARANCE - 1e-4 and walls >= walk.CLEARANCE - 1e-4
    assert agents / side**2 == pytest.approx(walk.DENSITY)
    moved = positions.copy()
    moved[1] = moved[0] + [0.3, 0.0]  # the control: two bodies 0.3 m apart overlap
    assert _least_gaps(moved, side)[0] < 0


def test_the_table_is_replaced_between_the_markers_or_added_as_a_section(tmp_path):
    page = tmp_path / "docs" / "performance.md"
    walk.write_docs(page, "first table")
    walk.write_docs(page, "second table")
    text = page.read_text()
    assert text.count(walk.SECTION) == 1 and "first table" not in text and "second table" in text
    assert text.startswith("# Performance\n")
    page.write_text("# Performance\n\nkept\n")
    walk.write_docs(page, "table")
    start, end = walk.MARKERS
    assert page.read_text() == f"# Performance\n\nkept\n\n{walk.SECTION}\n\n{start}\ntable\n{end}\n"


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--agents", "100,x"], "--agents='100,x' is invalid: must be comma-separated integers in [10, 1,000,000]"),
        (["--agents", "5"], "--agents='5' is invalid"),
        (["--sim-time", "2.5"], "--sim-time=2.5 is invalid: must be a whole number of decisions of 1 s"),
        (["--only", "e2e", "--write-docs"], "--write-docs is invalid with --only='e2e'"),
    ],
)
def test_a_bad_walk_option_is_refused_in_one_line(args, fragment, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([*args, "--output", str(tmp_path / "bench.json")])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert exit_info.value.code == 2 and len(lines) == 1 and fragment in lines[0], lines
    assert list(tmp_path.iterdir()) == []


def _pages(tmp_path) -> dict:
    """Pages ``--write-docs`` cannot take: binary bytes, a FIFO (a read would block), stray markers."""
    start, end = walk.MARKERS
    binary = tmp_path / "binary.md"
    binary.write_bytes(bytes(range(256)) * 4)
    nul = tmp_path / "nul.md"
    nul.write_text("# Performance\n\x00\n")
    fifo = tmp_path / "fifo.md"
    os.mkfifo(fifo)
    lone = tmp_path / "lone.md"
    lone.write_text(f"# Performance\n\n{start}\nold table\n")
    reversed_ = tmp_path / "reversed.md"
    reversed_.write_text(f"# Performance\n\n{end}\nold table\n{start}\n")
    return {
        binary: "it is not UTF-8 text (byte 128 is 0x80)",
        nul: "it is not text (a NUL character",
        fifo: "it is not a regular file",
        lone: "its marker comments do not pair up (<!-- walk-bench:start --> 1x, <!-- walk-bench:end --> 0x",
        reversed_: "1x, <!-- walk-bench:end --> 1x, end first); must hold each once",
    }


def test_a_page_that_cannot_take_the_table_is_refused_before_the_benchmark(tmp_path, capsys, monkeypatch):
    """Binary bytes or a FIFO ended in a traceback or a hang after the walk ran, and no bench.json: now one line at
    the door, the walk never started and the page is untouched."""
    monkeypatch.setattr(walk, "run", lambda **_: pytest.fail("the benchmark ran"))
    pages = _pages(tmp_path)
    for page, fragment in pages.items():
        before = None if stat.S_ISFIFO(page.stat().st_mode) else page.read_bytes()
        with pytest.raises(SystemExit) as exit_info:
            main(["--only", "walk", "--output", str(tmp_path / "bench.json"), "--write-docs", str(page)])
        lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        assert exit_info.value.code == 2 and len(lines) == 1, lines
        assert lines[0].startswith(f"python -m pedrl.bench: error: --write-docs={str(page)!r} is invalid: "), lines
        assert fragment in lines[0] and "must " in lines[0], lines
        assert before is None or page.read_bytes() == before
    assert not (tmp_path / "bench.json").exists()


def test_an_absent_page_a_page_without_markers_and_one_with_both_are_taken(tmp_path):
    """The control: what write_docs handles (a new page, a new section, the table between the markers) passes."""
    start, end = walk.MARKERS
    plain, marked = tmp_path / "plain.md", tmp_path / "marked.md"
    plain.write_text("# Performance\n\nno markers here\n")
    marked.write_text(f"# Performance\n\n{start}\nold table\n{end}\n")
    for page in (tmp_path / "absent.md", plain, marked):
        assert walk.page_problem(page) is None, page
        walk.write_docs(page, "table")
        assert walk.page_problem(page) is None, page  # and it can be written again
        assert page.read_text().count(start) == 1
