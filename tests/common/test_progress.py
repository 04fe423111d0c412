"""Progress on a terminal and in a log: a bar redraws in place; a log gets a line every few percent, never a redraw."""

from __future__ import annotations

import io

import pytest

from pedrl.common.progress import LineProgress, progress_bar


class Clock:
    """Seconds that a test moves on."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_a_line_every_ten_percent_of_a_slow_count():
    stream, clock = io.StringIO(), Clock()
    bar = LineProgress(200, "100 agents", unit="decisions", stream=stream, clock=clock, min_seconds=5.0)
    for _ in range(200):
        clock.now += 1.0  # a decision a second: every 10 % is 20 s after the last
        bar.update(1)
        bar.set_postfix(agents_left=7)
    bar.close()
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue()
    assert len(lines) == 10
    assert lines[0] == "100 agents:  10 % (20/200 decisions, 20 s, at most 180 s left; agents_left=7)"
    assert lines[-1] == "100 agents: 100 % (200/200 decisions, 200 s; agents_left=7)"


def test_a_fast_count_writes_only_its_last_line():
    stream, clock = io.StringIO(), Clock()
    bar = LineProgress(1000, "runs", unit="decisions", stream=stream, clock=clock, min_seconds=5.0)
    for _ in range(1000):
        clock.now += 0.001
        bar.update(1)
    assert stream.getvalue().splitlines() == ["runs: 100 % (1000/1000 decisions, 1 s)"]


def test_a_jump_over_several_steps_writes_one_line():
    stream, clock = io.StringIO(), Clock()
    bar = LineProgress(100, "x", unit="steps", stream=stream, clock=clock, min_seconds=0.0)
    clock.now = 3.0
    bar.update(35)
    bar.update(5)  # 40 %: another step passed
    bar.update(1)  # 41 %: none
    assert [line.split(" (")[0] for line in stream.getvalue().splitlines()] == ["x:  35 %", "x:  40 %"]


def test_a_count_that_stops_short_says_nothing_more():
    stream, clock = io.StringIO(), Clock()
    bar = LineProgress(100, "x", unit="steps", stream=stream, clock=clock, min_seconds=0.0)
    bar.update(5)
    bar.close()
    assert stream.getvalue() == ""


@pytest.mark.parametrize(("stream", "bar_type"), [(io.StringIO(), "LineProgress"), (Terminal(), "tqdm")])
def test_progress_bar_draws_a_bar_only_on_a_terminal(stream, bar_type):
    bar = progress_bar(50, "label", unit="decision", stream=stream)
    bar.update(50)
    bar.close()
    assert type(bar).__name__ == bar_type
    written = stream.getvalue()
    assert ("\r" in written) == (bar_type == "tqdm")


def test_the_evaluation_writes_no_redraws_into_a_log(capsys, monkeypatch):
    # a batch large enough for progress (PROGRESS_AGENTS agents), stderr not a terminal (pytest's capture): lines only
    from pedrl.evaluation import engine

    class Room:
        num_replicas, num_agents = 100, 50

        class params:  # noqa: N801 - the room's settings, as RoomEnv.params
            max_decisions = 400

    monkeypatch.setattr("pedrl.common.progress.MIN_SECONDS", 0.0)
    progress = engine.CrowdProgress(Room(), "100 agents, runs 1-100")
    for decisions in range(0, 401, 4):
        progress(decisions, 5000 - decisions)
    progress.close()
    err = capsys.readouterr().err
    assert "\r" not in err
    assert len(err.splitlines()) == 10
    assert err.splitlines()[-1].startswith("100 agents, runs 1-100: 100 % (400/400 decisions")
