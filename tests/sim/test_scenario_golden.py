"""The paper's room through the general polygon geometry reproduces the rectangle-only simulation to the bit."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).parents[1] / "data"
FEATURE_TOLERANCE = 1e-5  # m or rad: a few units in the last place of the angles (see the test)
spec = importlib.util.spec_from_file_location("make_paper_room_golden", DATA / "make_paper_room_golden.py")
golden = importlib.util.module_from_spec(spec)
spec.loader.exec_module(golden)


@pytest.mark.parametrize("case", sorted(golden.CASES))
def test_paper_room_matches_the_rectangle_simulation_to_the_bit(case):
    """Features, positions, rewards, arrivals and crashes of seeded random walks, against the pre-polygon code: the
    shapely-built ``paper_room`` scenario, whose walls come in another order than the rectangle's.

    The features are compared to 1e-5: their angles come from torch's vectorised ``atan2``, whose last bit depends on
    the CPU (on an AMD EPYC whose torch CPU capability is AVX2, 702 of the stored file's angles differ by one unit in
    the last place). Everything the features decide (positions, rewards, arrivals, crashes) is equal to
    the bit."""
    stored = np.load(DATA / "paper_room_golden.npz")
    kwargs, decisions = golden.CASES[case]
    record = golden.simulate(kwargs, decisions)
    for key, value in record.items():
        expected = stored[f"{case}/{key}"]
        assert value.dtype == expected.dtype and value.shape == expected.shape, key
        if key == "features":
            np.testing.assert_allclose(value, expected, rtol=0, atol=FEATURE_TOLERANCE, err_msg=f"{case}/{key}")
        else:
            assert np.array_equal(value, expected), f"{case}/{key} differs in {np.sum(value != expected)} entries"
