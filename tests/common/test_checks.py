"""The shared one-line checks of :mod:`pedrl.common.checks` that relate two keys; every entry point's cases are in
its catalogue (``tests/test_train.py``, ``tests/test_evaluate.py``)."""

import pytest

from pedrl.common.checks import check_epsilons, check_trials_per_iteration, duration, shown


def test_exploration_may_stay_constant_or_decay_but_not_rise():
    assert check_epsilons(0.4, 0.1) == (0.4, 0.1)
    assert check_epsilons(0.3, 0.3) == (0.3, 0.3)  # the control: equal values keep it constant
    with pytest.raises(ValueError) as error:
        check_epsilons(0.1, 0.9)
    assert str(error.value) == (
        "epsilon_end=0.9 is invalid with epsilon_start=0.1: must be a number in [0, 0.1] (exploration decays from "
        "epsilon_start to epsilon_end; equal values keep it constant)"
    )


def test_too_few_trials_for_the_iterations_names_both_keys():
    assert check_trials_per_iteration(5, 5) == 5
    with pytest.raises(ValueError, match=r"^trials=2 is invalid with iterations=5: must be an integer in \[5, "):
        check_trials_per_iteration(2, 5)
    with pytest.raises(ValueError, match=r"^iterations=0 is invalid"):
        check_trials_per_iteration(2, 0)
    with pytest.raises(ValueError, match=r"^trials=2.5 is invalid: must be an integer in \[5, "):
        check_trials_per_iteration(2.5, 5)


def test_durations_read_in_their_unit():
    assert [duration(s) for s in (45, 720, 3 * 3600, 5 * 86400, 2 * 365.25 * 86400)] == [
        "45 s",
        "12 min",
        "3 h",
        "5 days",
        "2 years",
    ]


def test_a_long_value_is_shown_in_one_short_line_a_path_with_its_file_name():
    path = "/home/someone/" + "deep/" * 40 + "room.wkt"
    text = shown(path)
    assert text.startswith("'/home/someone/") and text.endswith(f"room.wkt' ({len(path)} characters)")
    assert len(text) < 110
    assert shown("short.wkt") == "'short.wkt'"
    assert shown(list(range(1000))).endswith("... (1000 items)")
    assert shown(10**200).endswith("... (201 characters)")
