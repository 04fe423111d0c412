"""What every test of the validation suite shares: the row it reports (:class:`TestResult`, and the rows of
:func:`not_applicable` and :func:`invariants_row`), the sizes of its runs (:class:`Budget`), and what it runs with
(:class:`Context`, which tallies the physical invariants of every run)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pedrl.analysis import Recording, Trajectories, trajectories_for_export, write_jupedsim_sqlite
from pedrl.scenarios import LIDDLE_WIDTHS, Scenario
from pedrl.validation.crowds import Crowd
from pedrl.validation.measures import InvariantTally


@dataclass
class TestResult:
    """One row of the report.

    Attributes:
        test: The test's name.
        passed: The verdict (always ``False`` when not ``applicable``).
        value: The measured value (``None`` when nothing could be measured).
        unit: Unit of ``value``.
        reference: The value or rule it is compared with.
        source: Where the reference comes from.
        details: Further measured numbers (plain values).
        applicable: ``False`` when the test cannot be run at the crowd's body size (``note`` says why).
        counted: ``False`` for the sanity row of invariants, which stays outside the pass count.
        note: Why a row is not applicable, or what else a reader needs.
        failed: The pass criteria not met, each naming its measured number and bound (``crossing time 17.5 s not in
            [5.84, 8.76] s``), in the order of the test's rule: empty when ``passed`` or not ``applicable``; every
            failed row names at least one (:func:`verdict`). ``value`` may meet its own bound while another
            criterion fails, so the report shows these beside ``FAIL``.
    """

    test: str
    passed: bool
    value: float | None
    unit: str
    reference: str
    source: str
    details: dict[str, Any] = field(default_factory=dict)
    applicable: bool = True
    counted: bool = True
    note: str = ""
    failed: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.passed = bool(self.passed)  # numpy verdicts become plain booleans
        if self.applicable and self.passed == bool(self.failed):
            raise ValueError(
                f"row {self.test!r} is inconsistent: passed={self.passed} with failed criteria {self.failed!r}"
                " (a pass names none, a failure at least one)"
            )

    @property
    def status(self) -> str:
        """``pass``, ``FAIL`` or ``n/a``."""
        return "n/a" if not self.applicable else ("pass" if self.passed else "FAIL")


@dataclass(frozen=True)
class Budget:
    """Sizes of the suite's runs: the published ones, or ``quick`` (a smoke run, not a verdict)."""

    quick: bool = False

    @property
    def replicas(self) -> int:
        return 1 if self.quick else 2

    @property
    def rimea_1_runs(self) -> int:
        return 1 if self.quick else 4

    @property
    def rimea_4_densities(self) -> tuple[float, ...]:
        """Start densities in Weidmann's scale (1/m^2)."""
        return (1.0, 3.0) if self.quick else (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)

    @property
    def rimea_9_agents(self) -> int:
        return 200 if self.quick else 1000

    @property
    def rimea_9_time(self) -> float:
        return 300.0 if self.quick else 1200.0

    @property
    def widths(self) -> tuple[float, ...]:
        return (1.2, 2.5) if self.quick else LIDDLE_WIDTHS


class NotApplicableError(Exception):
    """The test cannot host its crowd at the crowd's body radius."""


@dataclass
class Context:
    """What every test needs: the crowd, the budget, and the invariants tally every run feeds."""

    crowd: Crowd
    budget: Budget
    invariants: InvariantTally = field(default_factory=InvariantTally)
    test: str = ""  # the test running now
    trajectories: Path | None = None
    """A folder: the first run of every simulation is written there as a JuPedSim SQLite trajectory file,
    ``<test>_<k>.sqlite`` (k counts the test's simulations), with its walkable area."""
    _written: dict[str, int] = field(default_factory=dict)

    def run(self, scenario: Scenario, **run: Any) -> Recording:
        """Simulate ``scenario`` with the crowd and tally the invariants; :class:`NotApplicableError` when the crowd's
        bodies do not fit in the spawn areas (hand-placed crowds are placed by the test itself)."""
        if run.get("positions") is None:
            try:
                scenario.check_capacity(run["num_agents"], self.crowd.radius)
            except ValueError as err:
                raise NotApplicableError(str(err)) from None
        recording = self.crowd.simulate(scenario, **run)
        self.invariants.add(recording, scenario.walkable, scenario.exits, label=self.test)
        if self.trajectories is not None:
            count = self._written[self.test] = self._written.get(self.test, 0) + 1
            self.trajectories.mkdir(parents=True, exist_ok=True)
            path = self.trajectories / f"{self.test}_{count}.sqlite"
            write_jupedsim_sqlite(
                path, trajectories_for_export(Trajectories.of_run(recording, 0, scenario.analysis_geometry()))
            )
        return recording


def verdict(criteria: Iterable[tuple[bool, str]]) -> tuple[bool, list[str]]:
    """``(passed, failed)`` of a test's pass criteria, each ``(met, what was measured against which bound)``: passed
    when every criterion is met; ``failed`` the texts of those not met, in order (:attr:`TestResult.failed`)."""
    failed = [text for met, text in criteria if not met]
    return not failed, failed


def invariants_row(tally: InvariantTally) -> TestResult:
    """The sanity row of the physical invariants (outside the pass count)."""
    return TestResult(
        "invariants (sanity, not counted)",
        tally.passed,
        None if math.isinf(tally.min_gap) else tally.min_gap,
        "m (smallest gap between bodies)",
        "gap >= 0, wall clearance >= 0, nobody outside, step <= max speed / frame rate",
        "physical invariants of the model",
        {
            "frames": tally.frames,
            "agent_frames": tally.agent_frames,
            "min_wall_clearance_m": tally.min_wall_clearance,
            "outside_agent_frames": tally.outside,
            "max_step_over_limit": tally.max_step_ratio,
            "broken_in": sorted(tally.broken_in),
        },
        counted=False,
        failed=tally.broken(),
    )


def stopped(name: str, reason: str) -> TestResult:
    """The row of a test whose run the simulator stopped (``reason``): failed, nothing measured."""
    return TestResult(
        name,
        False,
        None,
        "",
        "the run stopped before its end",
        "",
        note=reason,
        failed=["the run stopped before its end"],
    )


def not_applicable(name: str, radius: float, reason: str) -> TestResult:
    """The row of a test whose crowd does not fit at ``radius``."""
    return TestResult(
        name,
        False,
        None,
        "",
        f"not applicable at radius {radius:g} m",
        "",
        applicable=False,
        note=reason,
    )
