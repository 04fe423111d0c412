"""The lanes test of the validation suite: bidirectional flow in Feliciani and Nishinari's corridor, at their flow
ratios 5:1, 4:2 and 3:3, against their order parameter and crossing times. It is not a RiMEA test.

Feliciani, C. and Nishinari, K. (2016), "Empirical analysis of the lane formation process in bidirectional
pedestrian flow", Phys. Rev. E 94, 032304: 54 persons in a 3 m wide corridor, 6 rows of 9 split between its two
waiting areas by the flow ratio (6:0, 5:1, 4:2, 3:3), walking to the other end through a 10 m measurement area. Their
order parameter (Eq. 6-7) and the published values (Table V: Phi; Table II: the time to cross the area) are quoted
from a public reimplementation (the CrowdRL lane-formation notebook, FabianPlum/CrowdRL,
``examples/08_lane_formation_test.ipynb``), which cites the paper's equations and tables; the paper itself is
paywalled and was not read here. docs/validation-suite.md gives the test's definition and pass rule.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final

import numpy as np

from pedrl.analysis import Recording
from pedrl.scenarios import Scenario, build_scenario
from pedrl.sim.geometry import spawn_counts
from pedrl.validation.framework import Context, NotApplicableError, TestResult, verdict
from pedrl.validation.measures import crossing_durations, face_to_face_share, lane_order_frames

LANES_SOURCE: Final = (
    "Feliciani and Nishinari (2016), Phys. Rev. E 94, 032304: Phi (Table V), crossing times (Table II); not a RiMEA"
    " test"
)
LANES_NAME: Final = "lanes in a bidirectional corridor (Feliciani and Nishinari)"
LANES_AGENTS: Final = 54
"""Persons in Feliciani and Nishinari's experiment (9 columns of 6 rows)."""
LANES_RATIOS: Final[dict[str, tuple[int, int]]] = {"5:1": (5, 1), "4:2": (4, 2), "3:3": (3, 3)}
"""The bidirectional flow ratios of the experiment (rows walking to +x : rows walking to -x); 6:0 is one-way, no
lanes to measure."""
LANES_JUDGED: Final = "3:3"
"""The ratio the verdict reads; the others are reported beside their published values."""
FELICIANI_PHI: Final = {"5:1": 0.824, "4:2": 0.881, "3:3": 0.938}
"""Feliciani and Nishinari's mean order parameter per ratio (Table V; standard deviations 0.130, 0.131, 0.105)."""
FELICIANI_CROSSING: Final = {"5:1": 7.31, "4:2": 7.27, "3:3": 7.33}
"""Their mean time (s) to cross the 10 m measurement area per ratio (Table II; 7.27 s at 6:0)."""
LANES_WINDOW: Final = (14.0, 24.0)
"""The 10 m measurement area (x, m) in the middle of the 38 m x 3 m corridor (as in JuPedSim's lane-formation
notebook, which rebuilds the experiment)."""
LANES_LENGTH: Final = 38.0
LANES_WIDTH: Final = 3.0
LANES_SPAWN: Final = 12.0
LANE_ROW: Final = 0.2
"""Width (m) of the rows of the order parameter (the 0.2 m grid of the reimplementation)."""
LANES_PHI_PASS: Final = 0.8
"""Ours (the project's target): Phi at 3:3 at least this."""
LANES_CHANCE_MARGIN: Final = 0.05
"""Ours: Phi at 3:3 must also exceed its chance level (directions shuffled) by this much; rows 0.2 m wide hold about
one agent each in a sparse area, where random mixing alone scores 0.6 to 0.85."""
LANES_CROSSING: Final = 7.3
"""Ours: the reference time (s) to cross 10 m, Feliciani and Nishinari's 7.27-7.33 s rounded."""
LANES_CROSSING_TOLERANCE: Final = 0.2
"""Ours: the mean time to cross may differ from :data:`LANES_CROSSING` by this share."""
LANES_MIN_AGENTS: Final = 10
"""Fewest agents in the measurement area for a frame to count."""
LANES_MIN_FRAMES: Final = 300
"""Fewest agent-frames (agents in the area, summed over the counted frames) for a verdict."""
LANES_MIN_CROSSED: Final = 0.5
"""Share of the agents that must walk through the area for the mean time to cross to count."""
LANES_SHUFFLES: Final = 8
"""Permutations per frame for the chance level."""


def lanes_corridor(ratio: tuple[int, int]) -> Scenario:
    """The 38 m x 3 m corridor, its 12 m ends holding the two groups in ``ratio`` (group 0, the first agents, walks
    to +x)."""
    return build_scenario(
        {"name": "corridor", "length": LANES_LENGTH, "width": LANES_WIDTH, "spawn_length": LANES_SPAWN, "ratio": ratio}
    )


def lanes_directions(ratio: tuple[int, int], agents: int = LANES_AGENTS) -> np.ndarray:
    """``(agents,)`` +1 / -1: the way each agent of a :func:`lanes_corridor` run walks."""
    plus, _ = spawn_counts(agents, ratio)
    return np.where(np.arange(agents) < plus, 1, -1)


def lanes(context: Context) -> TestResult:
    """Lanes in Feliciani and Nishinari's corridor: 54 agents at each flow ratio, the groups starting in the 12 m ends
    and walking to the other end. The 3:3 run is the test (not applicable when its crowd does not fit); a ratio whose
    larger group does not fit is reported as not run. Verdict: :func:`judge_lanes`."""
    runs: dict[str, tuple[Recording, np.ndarray]] = {}
    for index, (label, ratio) in enumerate(LANES_RATIOS.items()):
        try:
            recording = context.run(
                lanes_corridor(ratio),
                num_agents=LANES_AGENTS,
                replicas=context.budget.replicas if label == LANES_JUDGED else 1,
                max_time=120.0,
                seed=5 + index,
            )
        except NotApplicableError:
            if label == LANES_JUDGED:
                raise
            continue
        runs[label] = (recording, lanes_directions(ratio))
    return judge_lanes(runs)


def measure_lanes(recording: Recording, direction: np.ndarray) -> dict[str, float | int | None]:
    """The lanes measures of one ratio's runs: mean ``Phi`` and its chance level over the counted frames, the
    agent-frames counted and the mean agents in the 10 m area per counted frame, the mean time to cross the area
    with the share of agents that did, and the share of agent-frames in the area spent face to face with an oncoming
    walker (:func:`~pedrl.validation.measures.face_to_face_share`)."""
    phi, counts, chance = lane_order_frames(
        recording.positions,
        recording.in_room,
        direction,
        window=LANES_WINDOW,
        width=LANES_WIDTH,
        row=LANE_ROW,
        min_agents=LANES_MIN_AGENTS,
        shuffles=LANES_SHUFFLES,
    )
    times = crossing_durations(
        recording.positions, recording.in_room, direction, window=LANES_WINDOW, frame_rate=recording.frame_rate
    )
    agents = direction.size * recording.in_room.shape[0]
    facing = face_to_face_share(
        recording.positions, recording.in_room, direction, window=LANES_WINDOW, radius=recording.radius
    )
    return {
        "phi": float(phi.mean()) if phi.size else None,
        "phi_chance": float(chance.mean()) if chance.size else None,
        "agent_frames": int(counts.sum()),
        "agents_in_area": float(counts.mean()) if counts.size else None,
        "crossing_s": float(times.mean()) if times.size else None,
        "crossed_share": times.size / agents,
        "face_to_face_share": facing,
    }


def judge_lanes(runs: Mapping[str, tuple[Recording, np.ndarray]]) -> TestResult:
    """The lanes verdict on the runs of each flow ratio (``label -> (recording, direction)``).

    Passed on the 3:3 runs when they give at least 300 agent-frames of at least 10 agents (both ways), ``Phi`` is at
    least 0.8 and exceeds its chance level by 0.05, and at least half of the agents walked through the 10 m area, in
    a mean time within 20 % of 7.3 s. Every ratio's ``Phi`` and time to cross are reported beside Feliciani and
    Nishinari's.
    """
    measured = {label: measure_lanes(*run) for label, run in runs.items()}
    judged = measured.get(LANES_JUDGED)
    low, high = LANES_CROSSING * (1 - LANES_CROSSING_TOLERANCE), LANES_CROSSING * (1 + LANES_CROSSING_TOLERANCE)
    criteria = [(judged is not None, f"no run at {LANES_JUDGED}")]
    if judged is not None:
        phi, chance, crossing = judged["phi"], judged["phi_chance"], judged["crossing_s"]
        criteria += [
            (
                judged["agent_frames"] >= LANES_MIN_FRAMES,
                f"{judged['agent_frames']} agent-frames of >= {LANES_MIN_AGENTS} agents < {LANES_MIN_FRAMES}",
            ),
            (phi is not None, f"no Phi measured (no frame of >= {LANES_MIN_AGENTS} agents in the area)"),
            (phi is None or phi >= LANES_PHI_PASS, f"Phi {phi or 0:.3g} < {LANES_PHI_PASS:g}"),
            (
                phi is None or phi - chance >= LANES_CHANCE_MARGIN,
                f"Phi {phi or 0:.3g} < chance {chance or 0:.3g} + {LANES_CHANCE_MARGIN:g}",
            ),
            (
                judged["crossed_share"] >= LANES_MIN_CROSSED,
                f"{judged['crossed_share']:.0%} of the agents crossed < {LANES_MIN_CROSSED:.0%}",
            ),
            (crossing is not None, "nobody crossed the area"),
            (
                crossing is None or low <= crossing <= high,
                f"crossing time {crossing or 0:.1f} s not in [{low:.2f}, {high:.2f}] s",
            ),
        ]
    passed, failed = verdict(criteria)

    def per_ratio(key: str) -> dict[str, float | None]:
        return {
            label: None if (value := measured.get(label, {}).get(key)) is None else round(value, 3)
            for label in LANES_RATIOS
        }

    return TestResult(
        LANES_NAME,
        passed,
        None if judged is None else judged["phi"],
        "order parameter Phi at 3:3",
        f"ours: at 3:3, Phi >= {LANES_PHI_PASS:g} and >= chance + {LANES_CHANCE_MARGIN:g}, mean time to cross 10 m"
        f" in [{low:.2f}, {high:.2f}] s ({LANES_CROSSING:g} s +- {LANES_CROSSING_TOLERANCE:.0%}) by >="
        f" {LANES_MIN_CROSSED:.0%} of the agents, >= {LANES_MIN_FRAMES} agent-frames of >= {LANES_MIN_AGENTS}"
        " agents; Feliciani and Nishinari: Phi 0.938, 7.33 s",
        LANES_SOURCE,
        {
            "phi": per_ratio("phi"),
            "phi_feliciani": dict(FELICIANI_PHI),
            "phi_chance": per_ratio("phi_chance"),
            "crossing_s": per_ratio("crossing_s"),
            "crossing_feliciani_s": dict(FELICIANI_CROSSING),
            "crossed_share": per_ratio("crossed_share"),
            "agents_in_area": per_ratio("agents_in_area"),
            "face_to_face_share": per_ratio("face_to_face_share"),
            "agent_frames": {label: measured.get(label, {}).get("agent_frames") for label in LANES_RATIOS},
        },
        failed=failed,
    )
