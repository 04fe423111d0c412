"""The validation suite of ``pedrl-validate``: RiMEA tests, Weidmann, Liddle's bottleneck flows, lanes, invariants."""

from pedrl.validation.suite import TESTS, Budget, Invariants, TestResult, run_suite

__all__ = ["TESTS", "Budget", "Invariants", "TestResult", "run_suite"]
