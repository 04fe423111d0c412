"""The fit of the continuous walking layer's time gap (``python -m pedrl.validation.calibrate``)."""

import pytest

from pedrl.validation import calibrate


def test_the_preset_layer_is_the_continuous_one():
    env = calibrate.experiment_env("pedestrian_walk")
    motion = env["motion"]
    assert (motion["name"], motion["contact"], motion["time_gap"], motion["order"]) == (
        "continuous",
        "yield",
        0.4,
        "door_first",
    )
    assert (env["agent_radius"], env["max_speed"]) == (0.2, 1.34)


@pytest.mark.slow
def test_the_fitted_layer_walks_weidmann_and_liddle_and_jupedsims_default_time_gap_misses_liddle():
    """The greedy walker on experiment=pedestrian_walk's layer passes RiMEA 4 and the bottleneck flows at the fitted
    0.4 s; the control, JuPedSim's default time gap of 1 s, gives flows about half of Liddle's."""
    env = calibrate.experiment_env("pedestrian_walk")
    fitted = calibrate.score(env)
    assert fitted["rimea_4"] <= calibrate.BANDS["rimea_4"] and fitted["bottleneck"] <= calibrate.BANDS["bottleneck"]
    default = calibrate.score({**env, "motion": {**env["motion"], "time_gap": 1.0}})
    assert default["bottleneck"] > 2 * calibrate.BANDS["bottleneck"]


def test_the_fit_takes_the_time_gap_whose_worse_band_share_is_smallest(monkeypatch):
    measured = {0.3: (0.33, 0.05), 0.4: (0.25, 0.15), 0.5: (0.2, 0.3)}  # rimea_4 RMS, bottleneck error

    def fake(env, *, seed=0):
        rms, error = measured[env["motion"]["time_gap"]]
        return {"rimea_4": rms, "bottleneck": error, "score": max(rms / 0.335, error / 0.25)}

    monkeypatch.setattr(calibrate, "score", fake)
    chosen, rows = calibrate.fit({}, [0.3, 0.4, 0.5])
    assert chosen == 0.4 and [row["time_gap"] for row in rows] == [0.3, 0.4, 0.5]
