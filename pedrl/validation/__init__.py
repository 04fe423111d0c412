"""The validation suite of ``pedrl-validate``: RiMEA tests 1, 4, 6 and 9, Liddle's bottleneck flows, lanes."""

from pedrl.analysis import Recording
from pedrl.validation.measures import InvariantTally
from pedrl.validation.suite import TEST_NAMES, TESTS, Budget, TestResult, run_suite

__all__ = ["TESTS", "TEST_NAMES", "Budget", "InvariantTally", "Recording", "TestResult", "run_suite"]
