"""The ``walk`` section of ``python -m pedrl.bench``: pedrl's continuous walking layer against JuPedSim's collision-free
speed model, in the same scene, from 100 to 100,000 agents.

The scene (:func:`hall`, :func:`start_positions`): a square hall of side ``L = sqrt(N / DENSITY)`` (the same density
at every size: 100,000 agents in 500 m x 500 m), an exit of :data:`EXIT_WIDTH` centred in each side; N bodies of
radius :data:`RADIUS` on a jittered lattice (non-overlapping by construction, the same for both simulators), each
walking to its nearest exit (:func:`nearest_exits`) at :data:`DESIRED_SPEED` with the time gap :data:`TIME_GAP`, at
steps of :data:`TIME_STEP`, for the same simulated time.

- pedrl (:func:`walk_pedrl`): one room (R = 1) of N agents, ``motion=continuous``
  (:class:`~pedrl.sim.motion.Continuous`, contact ``yield``, ``order=door_first`` as the main job's room), the
  ``goal`` action frame, decisions of the room's default length (1 s) and 20 sub-steps of 0.05 s inside; every agent
  walked by the greedy walker (top speed straight at its exit) through ``pedrl-eval``'s path, the fused trial
  (:func:`pedrl.trial.fused.record_trial_fused`: per decision ``act_room``, then ``sense_room`` and the greedy
  choice, every frame recorded).
- JuPedSim (:func:`walk_jupedsim`): ``CollisionFreeSpeedModel`` with the same speed, time gap, radius and ``dt``
  (:func:`pedrl.integrations.jupedsim.build_simulation`, an exit apron behind each exit), stepped by ``iterate``.

Each size and simulator runs in its own process (``python -m pedrl.bench.walk``, :func:`measure`) on one thread:
``torch.set_num_threads(1)`` and ``NUMBA_NUM_THREADS``, ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS`` = 1 in its
environment (the fused trial runs one room on one numba thread; JuPedSim's core is single-threaded, no OpenMP).

Metrics, per size and simulator:
    - ``wall_s``: the walk alone: neither building the scene nor numba's compile (a small trial warms it up first).
    - ``agent_steps``: the agents in the hall summed over the 0.05 s steps (pedrl counts an agent for the whole
      decision in which it leaves); ``agent_steps_per_s`` = ``agent_steps / wall_s``, and per core (over ``threads``).
    - ``peak_rss_mib``: the process's peak resident memory (``ru_maxrss``), and ``peak_growth_mib`` its growth over
      the peak before the scene was built (imports, the warm-up).
    - ``agents_left``: who walked out of the hall; ``ratio`` pedrl over JuPedSim in agent-steps per second per core;
      ``time_per_agent_step_10000_over_1000``: linearity (1 is linear).
"""

from __future__ import annotations

import json
import math
import os
import platform
import resource
import stat
import subprocess
import sys
import time
from pathlib import Path
from typing import Final

import numpy as np
import torch

from pedrl.scenarios import Scenario
from pedrl.scenarios import hall as hall_scenario
from pedrl.sim import RoomParams
from pedrl.sim.actions import GOAL_SPEED_RATIOS, GOAL_TURN_RATIOS
from pedrl.sim.motion import Continuous

__all__ = [
    "SIZES",
    "hall",
    "measure",
    "nearest_exits",
    "page_problem",
    "parse_agents",
    "run",
    "start_positions",
    "write_docs",
]

DENSITY: Final = 0.4
"""Persons per square metre at the start, at every size."""
RADIUS: Final = 0.2
"""Body radius (m), JuPedSim's default."""
TIME_STEP: Final = 0.05
"""Step (s): pedrl's sub-step (a 1 s decision in 20) and JuPedSim's ``dt``."""
TIME_GAP: Final = 0.4
"""T (s) of the collision-free speed rule, on both sides."""
DESIRED_SPEED: Final = 1.34
"""Free walking speed (m/s): pedrl's ``max_speed``, the greedy walker's speed, and JuPedSim's ``desired_speed``."""
EXIT_WIDTH: Final = 2.0
"""Width (m) of the exit centred in each side of the hall."""
CLEARANCE: Final = 0.01
"""Least gap (m) between two bodies, or a body and a wall, at the start."""
SIZES: Final = (100, 1_000, 10_000, 100_000)
"""Agents per run."""
QUICK_SIZES: Final = (100, 1_000)
SIM_TIME: Final = 10.0
"""Simulated seconds per run (``--sim-time``); ``--quick``: :data:`QUICK_SIM_TIME`."""
QUICK_SIM_TIME: Final = 3.0
MIN_AGENTS, MAX_AGENTS = 10, 1_000_000
"""The sizes ``--agents`` takes (10 agents: a hall of 5 m)."""
MAX_SIM_TIME: Final = 3600.0
SIMULATORS: Final = ("pedrl", "jupedsim")
MARKERS: Final = ("<!-- walk-bench:start -->", "<!-- walk-bench:end -->")
"""The comments between which ``--write-docs`` writes the table into docs/performance.md."""
SECTION: Final = "## The walking layer against JuPedSim"
MAX_PAGE_BYTES: Final = 10 * 2**20
"""Largest page ``--write-docs`` reads and rewrites (a Markdown page; docs/performance.md is a few kB)."""
THREAD_VARIABLES: Final = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


# ---------------------------------------------------------------------- the scene
def hall_side(agents: int) -> float:
    """The hall's side (m) for ``agents`` at :data:`DENSITY`."""
    return math.sqrt(agents / DENSITY)


def hall(agents: int) -> Scenario:
    """The square hall of ``agents`` (``scenario=hall``), an exit of :data:`EXIT_WIDTH` centred in each side (bottom,
    right, top, left)."""
    side = hall_side(agents)
    return hall_scenario(width=side, length=side, exit_width=EXIT_WIDTH, exits_per_side=1, spawn_margin=0.0)


def start_positions(agents: int, *, seed: int = 0) -> np.ndarray:
    """``(N, 2)`` float32 centres (m): ``N`` sites drawn from a square lattice over the hall, each moved by a uniform
    jitter that keeps every body :data:`CLEARANCE` clear of its neighbours and the walls (by construction: no
    ``(N, N)`` test)."""
    cells = math.ceil(math.sqrt(agents))
    spacing = hall_side(agents) / cells
    slack = spacing / 2 - RADIUS - CLEARANCE
    rng = np.random.default_rng(seed)
    row, column = np.divmod(rng.permutation(cells * cells)[:agents], cells)
    centres = (np.stack([column, row], -1) + 0.5) * spacing
    return (centres + rng.uniform(-slack, slack, (agents, 2))).astype(np.float32)


def nearest_exits(positions: np.ndarray, scenario: Scenario) -> np.ndarray:
    """``(N,)`` int64: the exit whose centre is nearest to each centre (pedrl's choice in a convex room without
    ``queue_weight``: the shortest straight route to an exit's goal point), for JuPedSim's journeys."""
    centres = np.array([exit_.interpolate(0.5, normalized=True).coords[0] for exit_ in scenario.exits])
    offsets = positions[:, None, :].astype(np.float64) - centres[None]
    return (offsets**2).sum(-1).argmin(-1).astype(np.int64)


def room_params(decisions: int) -> RoomParams:
    """The pedrl room's settings for a trial of ``decisions`` decisions."""
    motion = Continuous(contact="yield", time_gap=TIME_GAP, order="door_first", time_step=TIME_STEP)
    return RoomParams(
        agent_radius=RADIUS, max_speed=DESIRED_SPEED, max_decisions=decisions, motion=motion, action_frame="goal",
        speed_ratios=GOAL_SPEED_RATIOS, turn_ratios=GOAL_TURN_RATIOS,
    )  # fmt: skip


def _decisions(sim_time: float) -> int:
    return round(sim_time / room_params(1).decision_length)


def check_sim_time(sim_time: float) -> float:
    """``sim_time`` (s) if it is a whole number of the room's decisions, else a one-line ``ValueError``."""
    length = room_params(1).decision_length
    if not 0 < sim_time <= MAX_SIM_TIME or abs(sim_time / length - round(sim_time / length)) > 1e-9:
        raise ValueError(
            f"--sim-time={sim_time!r} is invalid: must be a whole number of decisions of {length:g} s (the room's"
            f" decision length), in (0, {MAX_SIM_TIME:g}] s"
        )
    return float(sim_time)


def parse_agents(text: str) -> tuple[int, ...]:
    """``--agents``: comma-separated integers in ``[MIN_AGENTS, MAX_AGENTS]``, else a one-line ``ValueError``."""
    try:
        sizes = tuple(int(value) for value in text.split(","))
    except ValueError:
        sizes = ()
    if not sizes or not all(MIN_AGENTS <= size <= MAX_AGENTS for size in sizes):
        raise ValueError(
            f"--agents={text!r} is invalid: must be comma-separated integers in [{MIN_AGENTS}, {MAX_AGENTS:,}],"
            " e.g. 100,1000"
        )
    return sizes


# ---------------------------------------------------------------------- one walk of each simulator
def walk_pedrl(agents: int, sim_time: float, *, seed: int = 0) -> dict:
    """pedrl's walk of the scene (module docstring), timed; the room refuses in one line what it cannot hold."""
    from pedrl.sim.controllers import GreedyDoorController
    from pedrl.trial.crowd import choose_path, run_crowd

    scenario, positions = hall(agents), start_positions(agents, seed=seed)
    env = scenario.room(room_params(_decisions(sim_time)), num_agents=agents)
    env.place(seed=seed, options={"positions": torch.from_numpy(positions)[None]})  # the fused trial's reset
    walker = GreedyDoorController()
    choose_path([env], walker, True, record=True, placed=True)  # one line where the fused trial cannot run
    start = time.perf_counter()
    record = run_crowd(env, walker, fused=True, record=True, start="placed").record
    seconds = time.perf_counter() - start
    return {
        "wall_s": seconds,
        "agent_steps": int(record.speed_count.sum()) * env.num_substeps,
        "agents_left": int(record.left.sum()),
        "same_exits_share": float((env.exit_index[0].numpy() == nearest_exits(positions, scenario)).mean()),
        "time_step_s": env.params.decision_length / env.num_substeps,
    }


def walk_jupedsim(agents: int, sim_time: float, *, seed: int = 0) -> dict:
    """JuPedSim's walk of the scene (module docstring), timed: ``iterate`` until the simulated time or the hall is
    empty. An agent counts in the hall until ``removed_agents`` lists it."""
    from pedrl.integrations.jupedsim import JuPedSimModel, build_simulation

    scenario, positions = hall(agents), start_positions(agents, seed=seed)
    params = room_params(1)
    dt = params.decision_length / params.num_substeps
    model = JuPedSimModel(desired_speed=DESIRED_SPEED, time_gap=TIME_GAP, radius=RADIUS, dt=dt)
    simulation = build_simulation(
        scenario,
        positions=positions.astype(np.float64),
        exit_index=nearest_exits(positions, scenario),
        waypoints=[()] * agents,
        model=model,
    )
    in_hall, agent_steps = agents, 0
    start = time.perf_counter()
    for _ in range(_decisions(sim_time) * params.num_substeps):
        if in_hall == 0:
            break
        agent_steps += in_hall
        simulation.iterate()
        in_hall -= len(simulation.removed_agents())
    seconds = time.perf_counter() - start
    return {"wall_s": seconds, "agent_steps": agent_steps, "agents_left": agents - in_hall, "time_step_s": dt}


def _peak_mib() -> float:
    """The process's peak resident memory (MiB; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure(simulator: str, agents: int, sim_time: float, *, seed: int = 0) -> dict:
    """One walk of ``simulator`` with its rates and memory (module docstring); a one-line refusal of the room or of
    JuPedSim is ``{"error": ...}``."""
    from pedrl.common.checks import first_line

    if simulator == "pedrl":
        walk_pedrl(MIN_AGENTS, room_params(1).decision_length)  # compiles the fused trial, or loads it
    else:
        import jupedsim  # noqa: F401  (its import in the baseline memory, as numba's warm-up in pedrl's)
    base = _peak_mib()
    try:
        result = {"pedrl": walk_pedrl, "jupedsim": walk_jupedsim}[simulator](agents, sim_time, seed=seed)
    except ValueError as err:  # the room's, or JuPedSim's, one-line refusal
        return {"error": first_line(err)}
    except MemoryError:
        return {"error": f"out of memory with {agents:,} agents"}
    threads = 1  # JuPedSim's core is sequential; the fused trial runs its one room in one thread
    rate = result["agent_steps"] / result["wall_s"] if result["wall_s"] > 0 else math.nan
    peak = _peak_mib()
    return {
        **result,
        "agent_steps_per_s": rate,
        "threads": threads,
        "agent_steps_per_s_per_core": rate / threads,
        "peak_rss_mib": peak,
        "peak_growth_mib": peak - base,
    }


# ---------------------------------------------------------------------- every size, each in its own process
def _in_subprocess(simulator: str, agents: int, sim_time: float) -> dict:
    """:func:`measure` in a fresh process of one thread (module docstring): its result, or ``{"error": ...}``."""
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, **dict.fromkeys(THREAD_VARIABLES, "1")}
    env["PYTHONPATH"] = os.pathsep.join(part for part in (root, env.get("PYTHONPATH")) if part)
    command = [sys.executable, "-m", "pedrl.bench.walk", simulator, str(agents), repr(sim_time)]
    done = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        last = (done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1]
        return {"error": f"the {simulator} process failed: {last}"}
    return json.loads(lines[-1])


def run(
    *, quick: bool = False, sizes: tuple[int, ...] | None = None, sim_time: float | None = None, docs: str | None = None
) -> dict:
    """Both simulators at every size (``sizes``, default :data:`SIZES`, ``quick`` :data:`QUICK_SIZES`) for
    ``sim_time`` s (default :data:`SIM_TIME`, ``quick`` :data:`QUICK_SIM_TIME`); with ``docs``, the table written into
    that page between :data:`MARKERS`. JuPedSim is skipped, with a note, where it is not installed.

    Returns:
        ``{"walk": {"settings", "sizes": {"<N>": {"agents", "hall_side_m", "pedrl", "jupedsim", "ratio"}},
        "time_per_agent_step_10000_over_1000", "table"}}``.
    """
    from pedrl.integrations.jupedsim import INSTALL_HINT, installed

    sizes = sizes or (QUICK_SIZES if quick else SIZES)
    sim_time = sim_time or (QUICK_SIM_TIME if quick else SIM_TIME)
    skip = None if installed() else {"skipped": INSTALL_HINT}
    if skip:
        print(f"  walk: JuPedSim skipped ({INSTALL_HINT})", flush=True)
    rows = {}
    for agents in sizes:
        row: dict = {"agents": agents, "hall_side_m": hall_side(agents)}
        for simulator in SIMULATORS:
            row[simulator] = skip if simulator == "jupedsim" and skip else _in_subprocess(simulator, agents, sim_time)
        rates = [row[s].get("agent_steps_per_s_per_core") for s in SIMULATORS]
        row["ratio"] = rates[0] / rates[1] if None not in rates and rates[1] > 0 else None
        print(f"  walk N={agents:,}: " + "; ".join(_summary(s, row[s]) for s in SIMULATORS), flush=True)
        rows[str(agents)] = row
    result = {
        "settings": _settings(sim_time),
        "sizes": rows,
        "time_per_agent_step_10000_over_1000": {s: _linearity(rows, s) for s in SIMULATORS},
    }
    result["table"] = table(result)
    print(result["table"], flush=True)
    if docs is not None:
        write_docs(Path(docs), result["table"])
        print(f"wrote the walk table into {docs}", flush=True)
    return {"walk": result}


def _settings(sim_time: float) -> dict:
    import importlib.metadata

    try:
        version = importlib.metadata.version("jupedsim")
    except importlib.metadata.PackageNotFoundError:
        version = None
    return {
        "density_per_m2": DENSITY, "radius_m": RADIUS, "time_step_s": TIME_STEP, "time_gap_s": TIME_GAP,
        "desired_speed_m_s": DESIRED_SPEED, "exit_width_m": EXIT_WIDTH, "sim_time_s": sim_time,
        "decision_length_s": room_params(1).decision_length, "motion": repr(room_params(1).motion),
        "threads": "1 per process: torch.set_num_threads(1), NUMBA/OMP/MKL_NUM_THREADS=1; JuPedSim single-threaded",
        "jupedsim": version, "machine": _machine(),
    }  # fmt: skip


def _machine() -> str:
    """The CPU's model name and the cores, as Linux names them (else what ``platform`` knows)."""
    try:
        names = [line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                 if line.startswith("model name")]  # fmt: skip
    except OSError:
        names = []
    return f"{names[0] if names else platform.processor() or platform.machine()}, {os.cpu_count()} cores"


def _summary(simulator: str, result: dict) -> str:
    if "agent_steps_per_s" not in result:
        return f"{simulator} {result.get('error') or result.get('skipped')}"
    return f"{simulator} {_count(result['agent_steps_per_s'])} agent-steps/s, {result['agents_left']} left"


def _linearity(rows: dict, simulator: str) -> float | None:
    """Time per agent-step at 10,000 agents over that at 1,000 (None without both)."""
    times = []
    for size in ("1000", "10000"):
        result = rows.get(size, {}).get(simulator, {})
        if "agent_steps" not in result or not result["agent_steps"]:
            return None
        times.append(result["wall_s"] / result["agent_steps"])
    return times[1] / times[0]


def _count(value: float) -> str:
    """1.23M, 456k, 789."""
    for size, suffix in ((1e6, "M"), (1e3, "k")):
        if value >= size:
            return f"{value / size:.3g}{suffix}"
    return f"{value:.3g}"


def table(result: dict) -> str:
    """The markdown table of a ``walk`` result, with the linearity line and the notes of the runs that failed."""
    settings = result["settings"]
    lines = [
        f"{settings['sim_time_s']:g} s simulated at {settings['density_per_m2']} persons/m^2, radius"
        f" {settings['radius_m']} m, steps of {settings['time_step_s']} s, time gap {settings['time_gap_s']} s,"
        f" {settings['desired_speed_m_s']} m/s; one thread each; {settings['machine']}, JuPedSim"
        f" {settings['jupedsim']} (`python -m pedrl.bench --only walk`):",
        "",
        "| agents | hall side | simulator | wall time (s) | agent-steps/s | per core | pedrl / JuPedSim"
        " | peak memory (MiB) | left the hall |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    notes = []
    for row in result["sizes"].values():
        for simulator, name in zip(SIMULATORS, ("pedrl", "JuPedSim"), strict=True):
            run, head = row[simulator], f"| {row['agents']:,} | {row['hall_side_m']:.1f} m | {name} |"
            if "agent_steps_per_s" not in run:
                notes.append(f"- {name} at {row['agents']:,} agents: {run.get('error') or run.get('skipped')}")
                lines.append(f"{head} - | - | - | - | - | - |")
                continue
            ratio = f"{row['ratio']:.2f}x" if simulator == "pedrl" and row["ratio"] is not None else ""
            lines.append(
                f"{head} {run['wall_s']:.3g} | {_count(run['agent_steps_per_s'])} |"
                f" {_count(run['agent_steps_per_s_per_core'])} | {ratio} | {run['peak_rss_mib']:.0f}"
                f" (+{run['peak_growth_mib']:.0f}) | {run['agents_left']:,} |"
            )
    linear = result["time_per_agent_step_10000_over_1000"]
    shown = [f"{name} {linear[s]:.2f}" for s, name in zip(SIMULATORS, ("pedrl", "JuPedSim"), strict=True) if linear[s]]
    if shown:
        lines += ["", f"Time per agent-step at 10,000 agents over that at 1,000 (1 is linear): {', '.join(shown)}."]
    return "\n".join(lines + ([""] + notes if notes else []))


def page_problem(page: str | os.PathLike) -> str | None:
    """Why :func:`write_docs` cannot put its table into ``page``, in one line naming it; None when it can.

    ``page`` must be absent (it is created) or a regular file (not a FIFO, which would block the read, nor a device)
    of at most :data:`MAX_PAGE_BYTES` of UTF-8 text without NUL characters; if it holds either of :data:`MARKERS`, it
    must hold each once, the start before the end (else the table would land beside a stray marker). Checked before
    the benchmark runs; reads the page, writes nothing.
    """
    page = Path(page)
    where = f"--write-docs={str(page)!r} is invalid"
    allowed = "must be absent or a UTF-8 text page (its table goes between the markers, else in a new section)"
    try:
        info = page.stat()
    except FileNotFoundError:
        return None
    except OSError as err:
        return f"{where}: cannot read it ({err.strerror or err}); {allowed}"
    if not stat.S_ISREG(info.st_mode):
        return f"{where}: it is not a regular file (a FIFO, a socket or a device); {allowed}"
    if info.st_size > MAX_PAGE_BYTES:
        return f"{where}: it holds {info.st_size:,} bytes, more than {MAX_PAGE_BYTES:,}; {allowed}"
    try:
        text = page.read_bytes().decode("utf-8")
    except OSError as err:
        return f"{where}: cannot read it ({err.strerror or err}); {allowed}"
    except UnicodeDecodeError as err:
        return f"{where}: it is not UTF-8 text (byte {err.start} is {err.object[err.start]:#04x}); {allowed}"
    if "\x00" in text:
        return f"{where}: it is not text (a NUL character at {text.index(chr(0))}); {allowed}"
    start, end = MARKERS
    counts = (text.count(start), text.count(end))
    ordered = counts == (1, 1) and text.index(start) < text.index(end)
    if counts != (0, 0) and not ordered:
        return (
            f"{where}: its marker comments do not pair up ({start} {counts[0]}x, {end} {counts[1]}x"
            f"{', end first' if counts == (1, 1) else ''}); must hold each once, the start first, or neither"
        )
    return None


def write_docs(page: Path, text: str) -> None:
    """Write ``text`` between :data:`MARKERS` in ``page``: in place of what they hold, else in a new section
    :data:`SECTION` at its end (a new page with a short title if there is none). :func:`page_problem` says first
    whether ``page`` can take it."""
    start, end = MARKERS
    old = (
        page.read_text(encoding="utf-8")
        if page.exists()
        else "# Performance\n\nHow fast pedrl runs, and how it is measured.\n"
    )
    block = f"{start}\n{text}\n{end}"
    if start in old and end in old.split(start, 1)[1]:
        before, rest = old.split(start, 1)
        new = before + block + rest.split(end, 1)[1]
    else:
        new = f"{old.rstrip()}\n\n{SECTION}\n\n{block}\n"
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(new, encoding="utf-8")


def _child() -> None:
    """``python -m pedrl.bench.walk SIMULATOR AGENTS SIM_TIME``: :func:`measure`'s JSON on its last line."""
    simulator, agents, sim_time = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    torch.set_num_threads(1)
    print(json.dumps(measure(simulator, agents, sim_time)))


if __name__ == "__main__":
    _child()
