"""One crowd loop and one choice of its path (`pedrl.trial.loop`, `pedrl.trial.crowd`).

Training (`gather`, `Trainer.run_trial`), `pedrl-eval` (`record_batch`) and `pedrl-validate` (`PedrlCrowd.simulate`) run
their torch trials through the one loop, `crowd_loop`, the only place of those packages that steps a room: a seeded
run through each equals the loop's own output, and the loop is the one that ran. Whether a trial runs through the
fused trial or that loop is chosen in one place, `pedrl.trial.crowd.choose_path`: read from the source with ``ast``,
nothing else in the package calls the fused trial's entry points, asks the room whether the fast path can run it,
or branches on the ``fused`` setting.
"""

import ast

import numpy as np
import pytest
import torch

from pedrl._numba import numba_available
from pedrl.evaluation.engine import record_batch
from pedrl.rl.policy import PolicyController, TabularPolicy
from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.motion import Simultaneous
from pedrl.trial import crowd
from pedrl.trial.crowd import choose_path, run_crowd
from pedrl.trial.loop import Learner, crowd_loop
from pedrl.trial.rollout import gather
from pedrl.validation.crowds import PedrlCrowd
from pedrl.vq.encoder import EncoderSettings, StateEncoder
from pedrl.vq.quantizer import Quantizer
from tests.test_layout import PACKAGE

CHOOSER = PACKAGE / "trial" / "crowd.py"
"""The one module that chooses the path of a trial and runs the fused trial."""
FUSED_ENTRY_POINTS = ("run_trial_fused", "record_trial_fused")
CHOICE_NAMES = ("fast_path_reason", "fused_reason", "room_reason", "controller_reason", "check_fused")
"""What decides whether the fast path can run: the room's allow-list and the former helpers around it."""


# ---------------------------------------------------------------------------------------------- the one choice
def choice_outside_the_chooser(source: str, *, in_sim: bool = False) -> list[str]:
    """What in ``source`` (a module other than the chooser) runs the fused trial or chooses its path: a reference
    to a fused entry point or to a choice helper (:meth:`RoomEnv.fast_path_reason` is the room's own inside
    ``pedrl/sim/``), and a branch (``if``, ``while``, a conditional expression, an ``assert``, a comprehension's
    ``if``) whose test reads a ``fused`` setting (a name, an attribute, or a ``"fused"`` key)."""
    found = []
    tree = ast.parse(source)
    allowed = {"fast_path_reason"} if in_sim else set()
    for node in ast.walk(tree):
        name = None
        if isinstance(node, ast.Name):
            name = node.id
        elif isinstance(node, ast.Attribute):
            name = node.attr
        elif isinstance(node, ast.alias):
            name = node.name
        if name in FUSED_ENTRY_POINTS or (name in CHOICE_NAMES and name not in allowed):
            found.append(f"line {node.lineno}: {name}" if hasattr(node, "lineno") else name)
        tests = []
        if isinstance(node, ast.If | ast.IfExp | ast.While | ast.Assert):
            tests.append(node.test)
        elif isinstance(node, ast.comprehension):
            tests.extend(node.ifs)
        for test in tests:
            for part in ast.walk(test):
                reads = (
                    (isinstance(part, ast.Name) and part.id == "fused")
                    or (isinstance(part, ast.Attribute) and part.attr == "fused")
                    or (isinstance(part, ast.Constant) and part.value == "fused")
                )
                if reads:
                    found.append(f"line {test.lineno}: a branch on fused ({ast.unparse(test)})")
    return found


def test_the_reader_finds_a_choice_in_every_form():
    """The rule's own control: each way the old code chose its path is found, a setting passed along is not."""
    chooses = [
        "from pedrl.trial.fused import record_trial_fused",
        "trace = fused.run_trial_fused(env, policy)",
        "if fused is not False:\n    pass",
        "reason = None if self.fused is False else 1",
        'if cfg.get("fused"):\n    check(cfg)',
        "while not settings['fused']:\n    pass",
        "reason = env.fast_path_reason()",
        "from pedrl.trial.fused import room_reason",
    ]
    for source in chooses:
        assert choice_outside_the_chooser(source), source
    passes = "run_trial(env, policy, fused=self.fused)\nrecord = run_crowd(env, c, fused=cfg.get('fused'))"
    assert choice_outside_the_chooser(passes) == []
    assert choice_outside_the_chooser("reason = self.params.fast_path_reason()", in_sim=True) == []


def test_only_the_chooser_runs_the_fused_trial_or_chooses_the_path():
    """Every module of the package but `pedrl/trial/crowd.py`: no call of the fused trial's entry points, no
    question to the fast path's allow-list (but the room's own, in `pedrl/sim/`), no branch on ``fused``."""
    chooser = CHOOSER.read_text()
    for name in FUSED_ENTRY_POINTS + ("fast_path_reason",):
        assert name in chooser  # the chooser is where they went: the rule reads the right module
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == CHOOSER:
            continue
        relative = path.relative_to(PACKAGE.parent)
        choices = choice_outside_the_chooser(path.read_text(), in_sim=relative.parts[1] == "sim")
        if choices:
            found[str(relative)] = choices
    assert not found, f"only pedrl/trial/crowd.py chooses the path of a trial: {found}"


CROWD_RUNNERS = ("trial", "algos", "evaluation", "validation")
"""The packages that run crowds of pedrl rooms: training, pedrl-eval, pedrl-validate."""
STEPPERS = (PACKAGE / "trial" / "loop.py", PACKAGE / "trial" / "twins.py")
"""Where a room is stepped: the one loop, and the twin harness (the torch path beside the kernels, decision by
decision)."""


def steps_a_room(source: str) -> list[int]:
    """The lines of ``source`` that call a ``step`` method (``env.step(actions)``)."""
    return [
        node.lineno
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "step"
    ]


def test_one_loop_steps_the_rooms_of_training_evaluation_and_validation():
    """Gathering, training, recording and validating a crowd all step their rooms through `crowd_loop`."""
    assert steps_a_room("obs, *_ = self.env.step(actions)") == [1]
    found = {}
    for package in CROWD_RUNNERS:
        for path in sorted((PACKAGE / package).rglob("*.py")):
            lines = steps_a_room(path.read_text())
            if lines and path not in STEPPERS:
                found[str(path.relative_to(PACKAGE.parent))] = lines
    assert not found, f"a crowd loop outside pedrl/trial/loop.py: {found}"


def test_fused_is_a_boolean_or_null_and_true_is_refused_in_one_line():
    greedy = GreedyDoorController()
    with pytest.raises(ValueError, match=r"^fused='yes' is invalid: must be true, false or null$"):
        choose_path([], None, "yes")
    simultaneous = paper_room(width=10.0, length=10.0).room(num_replicas=2, num_agents=3, motion=Simultaneous())
    with pytest.raises(ValueError, match=r"^fused=true is invalid: the fused trial cannot run with motion=simul"):
        choose_path([simultaneous], greedy, True)
    name, why_not = choose_path([simultaneous], greedy, None)
    assert name == "torch" and why_not.startswith("the fused trial cannot run with motion=simultaneous")
    assert choose_path([simultaneous], greedy, False) == ("torch", "fused=false")

    class Straight:
        def act(self, env, obs, info):
            return torch.full(env.active.shape, 76)

    room = paper_room(width=10.0, length=10.0).room(num_replicas=2, num_agents=3)
    with pytest.raises(ValueError, match=r"^fused=true is invalid: the fused trial cannot run with a Straight \("):
        choose_path([room], Straight(), True)
    learner = Learner(small_policy(room), epsilon=0.1, generator=torch.Generator(), learn=True)
    with pytest.raises(ValueError, match=r"^fused=true is invalid: .*a learning trial recorded"):
        choose_path([room], learner, True, record=True)
    if numba_available():
        assert choose_path([room], greedy, None) == ("fused", None)
        assert choose_path([room], learner, True) == ("fused", None)


# ---------------------------------------------------------------------------------------------- the one loop
def small_room() -> RoomEnv:
    return paper_room(width=8.0, length=8.0, door_width=3.0).room(num_replicas=4, num_agents=5, max_decisions=30)


def small_policy(env: RoomEnv, processes: int = 2) -> TabularPolicy:
    """Random tables over a quantizer of 24 prototypes fitted on a random walk, random void fillings (the encoder
    draws from the generator too)."""
    settings = EncoderSettings.for_room(env, void_features="random", distance_transform="log")
    generator = torch.Generator().manual_seed(0)
    env.reset(seed=0)
    states = gather(env, StateEncoder(settings), None, trials=1, epsilon=1.0, processes=processes, generator=generator)
    quantizer, _ = Quantizer.fit(states.states, 24, generator=generator, max_iterations=5)
    tables = torch.randn(processes, 1, 24, 81, generator=generator)
    return TabularPolicy(StateEncoder(settings, quantizer), tables, rooms_per_process=env.num_replicas // processes)


@pytest.fixture
def loop_calls(monkeypatch):
    """The calls of the one loop, counted as they pass (the loop itself runs)."""
    calls = []

    def counted(*args, **kwargs):
        calls.append(kwargs.get("record", False))
        return crowd_loop(*args, **kwargs)

    monkeypatch.setattr(crowd, "crowd_loop", counted)
    return calls


def test_training_s_torch_trial_is_the_loop_s(loop_calls):
    """A trainer's trial (run_crowd with a Learner, fused=False): the statistics and the learned tables of the loop
    run with a Learner, to the bit."""
    runs = []
    for through in ("run_crowd", "loop"):
        env = small_room()
        policy = small_policy(env)
        env.reset(seed=5)
        generator = torch.Generator().manual_seed(7)
        settings = dict(epsilon=0.3, generator=generator, learn=True, alpha=0.2, gamma=0.9)
        if through == "run_crowd":
            stats = [run_crowd(env, Learner(policy, **settings), fused=False).stats for _ in range(2)]
        else:
            stats = [crowd_loop(env, Learner(policy, **settings)).stats for _ in range(2)]
        runs.append((stats, policy.q_values))
    (mine, tables), (theirs, loop_tables) = runs
    assert loop_calls == [False, False]  # both trials of run_crowd went through the loop
    assert torch.equal(tables, loop_tables) and mine[1].agent_decisions > 0
    for a, b in zip(mine, theirs, strict=True):
        assert a.decisions == b.decisions and a.agent_decisions == b.agent_decisions
        for field in ("success_rate", "episodic_return", "crashes_agent", "mean_speed", "td_error", "door_flow"):
            torch.testing.assert_close(getattr(a, field), getattr(b, field), rtol=0, atol=0, equal_nan=True)


def test_the_evaluation_s_torch_recording_is_the_loop_s(loop_calls):
    """record_batch(fused=False) of a learned policy acting epsilon-greedily: the loop's recording, frame by frame,
    with the exit times of its exit decisions."""
    records = []
    for through in ("record_batch", "loop"):
        env = small_room()
        controller = PolicyController(small_policy(env), epsilon=0.2, generator=torch.Generator().manual_seed(3))
        env.reset(seed=11)
        if through == "record_batch":
            records.append(record_batch(env, controller, fused=False))
        else:
            records.append(crowd_loop(env, controller, record=True).record)
    batch, mine = records
    assert loop_calls == [True]
    assert np.array_equal(batch.positions, mine.positions) and np.array_equal(batch.velocities, mine.velocities)
    assert np.array_equal(batch.in_room, mine.in_room) and batch.positions.shape[1] > 5
    np.testing.assert_allclose(batch.exit_time, mine.exit_time, rtol=1e-6)
    assert batch.left.any() and np.array_equal(batch.left, mine.left)
    assert batch.exit_time.dtype == np.float32  # the evaluation's exit times
    for name in ("crashes", "wall_crashes", "speed_sum", "speed_sq_sum", "speed_count"):
        assert np.array_equal(getattr(batch, name), getattr(mine, name)), name


def test_the_validation_s_torch_recording_is_the_loop_s(loop_calls):
    """PedrlCrowd.simulate(fused=False) of the greedy walker with random actions, from its placement: the loop's
    recording from the same start."""
    from pedrl.scenarios import build_scenario

    scenario = build_scenario({"name": "bottleneck"})
    run = dict(num_agents=12, replicas=3, max_time=40.0, seed=2)
    recordings = []
    for through in ("simulate", "loop"):
        walker = GreedyDoorController(epsilon=0.3, generator=torch.Generator().manual_seed(4))
        placed = PedrlCrowd(walker, {"agent_radius": 0.25}, fused=False)
        if through == "simulate":
            recordings.append(placed.simulate(scenario, **run))
        else:
            env, start = placed.start(scenario, **run)
            recordings.append(crowd_loop(env, walker, record=True, start=start).record)
    recording, mine = recordings
    assert loop_calls == [True]
    assert np.array_equal(recording.positions, mine.positions) and np.array_equal(recording.in_room, mine.in_room)
    assert np.array_equal(recording.exit_time, mine.exit_time, equal_nan=True) and recording.left.any()
    assert recording.velocities is None and mine.velocities is not None  # the suite reads positions only


@pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")
def test_the_fused_recording_has_the_loop_s_form():
    """run_crowd's fused recording of the greedy walker is a Recording of the loop's shapes and types, and its
    statistics count the same agent-decisions as the recording."""
    results = []
    for fused in (False, True):
        env = small_room()
        env.reset(seed=3)
        results.append(run_crowd(env, GreedyDoorController(), fused=fused, record=True))
    for stats, record in results:
        rooms, frames, agents, _ = record.positions.shape
        assert record.in_room.shape == (rooms, frames, agents) and record.exit_time.dtype == np.float64
        assert stats.agent_decisions == int(record.speed_count.sum()) and stats.decisions == frames - 1
    (_, torch_record), (_, fused_record) = results
    for name, value in vars(torch_record).items():
        if isinstance(value, np.ndarray):
            assert getattr(fused_record, name).dtype == value.dtype, name
        else:  # the frame rate (every decision recorded on both), radius and speed limit
            assert getattr(fused_record, name) == value, name


@pytest.mark.parametrize("fused", [False, True], ids=["torch-loop", "fused"])
def test_the_td_error_is_each_process_own(fused):
    """TensorBoard's spread of the TD error over the processes was 0 on every trial: one pooled figure was copied
    to every process. Each process's own mean |TD error| now, whose pooled mean over their updates is the old one."""
    env = small_room()
    policy = small_policy(env)  # 2 processes of 2 rooms each, random tables: different errors per process
    env.reset(seed=5)
    learner = Learner(policy, epsilon=0.3, generator=torch.Generator().manual_seed(7), learn=True, alpha=0.2, gamma=0.9)
    stats = run_crowd(env, learner, fused=fused).stats
    assert stats.td_error.shape == (2,)
    assert bool(torch.isfinite(stats.td_error).all()) and bool((stats.td_error > 0).all())
    assert float(stats.td_error.double().std(unbiased=False)) > 1e-6  # a real spread over the processes
