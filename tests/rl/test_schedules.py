"""Exploration schedules."""

import pytest

from pedrl.rl import ConstantSchedule, ExponentialSchedule, LinearSchedule


def test_linear_schedule_values():
    schedule = LinearSchedule(start=0.4, end=0.0, decay_trials=100)
    assert schedule(0) == pytest.approx(0.4)
    assert schedule(25) == pytest.approx(0.3)
    assert schedule(50) == pytest.approx(0.2)
    assert schedule(100) == pytest.approx(0.0)
    assert schedule(1000) == pytest.approx(0.0)
    assert schedule(-5) == pytest.approx(0.4)
    values = [schedule(t) for t in range(120)]
    assert all(after <= before for before, after in zip(values, values[1:], strict=False))


def test_linear_schedule_without_decay_is_the_end_value():
    assert LinearSchedule(start=0.4, end=0.05, decay_trials=0)(0) == pytest.approx(0.05)


def test_linear_schedule_can_increase():
    assert LinearSchedule(start=0.0, end=1.0, decay_trials=4)(1) == pytest.approx(0.25)


def test_exponential_schedule_values():
    schedule = ExponentialSchedule(start=0.4, end=0.1, half_life=10)
    assert schedule(0) == pytest.approx(0.4)
    assert schedule(10) == pytest.approx(0.25)
    assert schedule(20) == pytest.approx(0.175)
    assert schedule(10_000) == pytest.approx(0.1)
    with pytest.raises(ValueError):
        ExponentialSchedule(start=0.4, end=0.1, half_life=0)


def test_constant_schedule():
    assert ConstantSchedule(0.07)(12345) == 0.07
